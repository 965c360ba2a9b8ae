"""gazeaug: semi-synthetic dataset augmentation for application-specific gaze estimation.

Built on :mod:`facemesh` (landmarks, head pose, textured face meshes and the
shared conventions in :mod:`facemesh.conventions`). The normalization,
head-pose sampling, eye-patch rendering, dataset and training stages are
added module by module; see docs/ for what exists today.
"""

from facemesh import __version__

__all__ = ["__version__"]
