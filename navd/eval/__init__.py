"""Offline analysis: evaluation reports, aiding logs, the gravity model for DOV grids."""
