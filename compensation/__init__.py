"""Geometric error model, identification and compensation (issue [6/7])."""
