"""GenICam camera adapter on harvesters (a GenTL producer from the config), a :class:`cellctl.ports.Camera`.

harvesters and genicam come with the optional extra ``camera`` (``pip install 'cellctl[camera]'``);
this package imports without them and says so when a camera is opened.
"""

from genicam_camera.camera import CameraInfo, GenicamCamera
from genicam_camera.pixels import MONO_BITS, to_mono8

__all__ = ["MONO_BITS", "CameraInfo", "GenicamCamera", "to_mono8"]
