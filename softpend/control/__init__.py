"""Classical control baselines: linearisation, LQR, PID and energy swing-up."""
