"""Shipped configuration (parameter YAML, default tissue image, RViz config) as package data."""
