"""Warm starts: where the projected Gauss-Seidel solver begins, the project's subject."""
