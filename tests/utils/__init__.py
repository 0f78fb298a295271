"""Tests of drem_maniskill.utils."""
