"""Tests of drem_maniskill.envs."""
