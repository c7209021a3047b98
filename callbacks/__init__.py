"""Stable-baselines3 callbacks for training and evaluating memory policies."""
