"""Geometry and contact mechanics shared by the models: kinematics and thread contact points."""
