"""Figures, DVC plot data and the report page, from predictions and metrics only."""
