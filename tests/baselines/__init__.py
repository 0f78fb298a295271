"""Tests of drem_maniskill.baselines."""
