"""memo_ros: model-based 3D human posture tracking from calibrated cameras."""

__version__ = '0.1.0'
