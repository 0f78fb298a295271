"""Tests of drem_maniskill.experts."""
