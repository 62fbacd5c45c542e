"""Model fidelity: the continuum-beam plant validated against beam theory, and the PRB chain compared with it."""
