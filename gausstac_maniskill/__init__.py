"""GaussTac for ManiSkill: visuo-tactile simulation for dexterous robot hands.

Soft fingertip pads and deformable objects are simulated with a Taichi MLS-MPM
co-simulator driven by rigid link poses (SAPIEN or MuJoCo); a 3D Gaussian
Splatting camera renders them. Units are SI throughout (m, kg, s, Pa).
"""

__version__ = "0.1.0"
