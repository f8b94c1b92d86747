"""Training and ONNX export of the psgrasp two-stage grasp network.

Stage 1 is a 3D residual U-Net that classifies every voxel of a 64³ normal grid as empty,
contact or gripper space; stage 2 is an MLP that maps trilinearly sampled multi-resolution
encoder features at a contact point to a Power-Spherical baseline distribution (ν, κ), an
opening width, a quality prior and 18 collision priors. The exported graphs and the decoding
rules follow ``docs``/``prompts`` network contract version 1 (see ``README.md``).
"""

__version__ = "0.1.0"

#: Network interface contract version written to ``card.json``.
FORMAT_VERSION = 1
