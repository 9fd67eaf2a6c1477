"""Geometry and mechanics shared by the models: kinematics, inertia and thread contact points."""
