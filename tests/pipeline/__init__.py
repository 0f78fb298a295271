"""Tests of drem_maniskill.pipeline."""
