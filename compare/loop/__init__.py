"""The closed loop and the plant it drives: control step, robot I/O, simulation, joint drive, waypoints, faults."""
