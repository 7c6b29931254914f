"""meshcat, imported once and quietly: meshcat 0.3.2 imports pyzmq's deprecated ``zmq.eventloop.ioloop`` (a
DeprecationWarning on every import) when its package loads."""

import warnings

with warnings.catch_warnings():
    warnings.filterwarnings("ignore", message="zmq.eventloop.ioloop is deprecated", category=DeprecationWarning)
    import meshcat.geometry as mg
    from meshcat.animation import js_quaternion
    from meshcat.path import Path as MeshcatPath

__all__ = ["MeshcatPath", "js_quaternion", "mg"]
