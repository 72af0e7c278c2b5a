"""The episode's stages over a MuJoCo world: mapping, placing a camera, moving
there with the pose corrected, looking for the targets, the insertion task; and the
episode that composes them."""
