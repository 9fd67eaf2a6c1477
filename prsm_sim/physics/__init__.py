"""Geometry and mechanics shared by the models: kinematics, inertia, thread contact points, Hertz contact
and load sharing. Pure functions of the parameter records, which they know by type only (imported for
annotations): `params` uses them to resolve derived values (the ISO 76 static rating)."""
