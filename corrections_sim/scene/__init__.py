"""The world: geometry, the Panda (pinocchio → CasADi FK, IK), environments, the MuJoCo scene
(collisions), its MJCF files and offscreen renders. The lowest layer: imports nothing above."""
