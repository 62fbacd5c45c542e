"""The hardware rig: motor link, rig emulator and twin, control loops, state estimator, stream synchronisation."""
