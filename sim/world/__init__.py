"""The MuJoCo world: the scene, rendering, sensing, optics, collision, IK, arm
planning and motion in physics."""
