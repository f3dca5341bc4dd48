"""Motion: the program model, exact timing (look-ahead linear moves, Ruckig joint moves), timelines and heaters."""
