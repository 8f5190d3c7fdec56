"""Anatomy-driven skin (Simmons et al. 2002): feature points, zoned RBF and morphing.

Takes a Character and its fitted muscles; gives feature points on the skin anchored to bones and
muscle lofts (`features`, with `resample` to insert them), geodesic zones (`zones`), the zoned RBF
interpolant (`rbf`, kernels in `rbf_kernels`), marker sets (`markers`), and a character morphed to
a target's markers (`morph`). Imports rig.base, rig.motion, rig.character, rig.muscle."""
