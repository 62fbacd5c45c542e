"""The hardware rig: serial motor link, rig emulator and digital twin, host control loops, state estimator, time
synchronisation of the motor and camera streams."""
