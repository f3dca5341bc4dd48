"""Collision checking of a program: robot and tool against table, plate and the growing part."""
