"""bezmotion: precise, character-agnostic motion in-betweening in JAX."""

from bezmotion.geometry import Skeleton, forward_kinematics, inverse_kinematics

__version__ = "0.1.0"
__all__ = ["Skeleton", "forward_kinematics", "inverse_kinematics", "__version__"]
