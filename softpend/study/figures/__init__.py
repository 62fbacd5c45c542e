"""Figures of the book: plotting functions over the results of the study."""
