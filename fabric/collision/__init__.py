"""Collision checking: every motion of a program (or one live move) certified for every robot body against
the table, the plate, the part as printed bead by bead, and the robot itself.

``certify.Certifier`` is the check (its module docstring has the design); ``sweep`` is version 1's sampled
sweep, kept to compare against (tools/bench/collision_bench.py).
"""
