"""File formats shared by the rig, the tracker and the study (sample logs)."""
