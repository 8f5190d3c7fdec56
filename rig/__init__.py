"""The character and its anatomy, stage by stage, bottom up: base (errors, files), motion (clips),
character (skin and weights), muscle (templates, fitting, static shapes), anatomy (feature points,
RBF, morphing), skin (LBS/DQS and the muscles' deformers). Geometry in NumPy first, kernels in Warp."""
