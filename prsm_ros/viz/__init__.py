"""Rerun output: the 3D scene, time series, blueprint, the live sink and bag conversion."""
