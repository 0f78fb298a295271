"""Tests of drem_maniskill.evaluate."""
