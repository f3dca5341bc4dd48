"""The digital twin: runs a program in simulated time (state machine, motion legs, deposition, calibration)."""
