"""Tests of drem_maniskill.rl."""
