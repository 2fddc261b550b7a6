"""Evaluating trained networks: inference over whole sequences, trajectories, metrics and their plots."""
