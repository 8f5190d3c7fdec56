"""Chains: secondary motion beyond tissue. The character's chains (rig.character.chains: tails, ears, hair, wing
fingers) and the animated pose at the goal knots in; each chain joint's swung rotation at the output times out.

`model.build` makes one MuJoCo model of every chain (capsules on ball joints, hung from heavy bodies driven along the
animation, colliding with the body's capsules and the floor); `params` holds the keyable per-chain parameters
(stiffness in Hz, damping ratio, gravity, drag) and their defaults from each chain's length; `simulate.swing` steps
it on a fixed grid (frame-rate independent, periodic for a looping bake) and `simulate.chain_world` puts the result
back on the skeleton; `measure` says how far each chain swung and whether it passed into the body.
Imports rig.* and sim.jiggle (its keyed curves: a chain's parameters key like a muscle's); below sim.bake."""
