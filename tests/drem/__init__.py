"""Tests of drem_maniskill.drem."""
