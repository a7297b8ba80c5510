"""Measurement models, one module per kind of aiding; each opens with its model equation."""
