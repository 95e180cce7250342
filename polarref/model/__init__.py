"""The data model: one reconstruction type, one observation type, and every pycolmap conversion.

* :class:`Reconstruction` (with :class:`Image`, :class:`Point3D`): cameras, posed images and 3D
  points by id; the type every stage hands on (SfM output, io readers, BA adapter, metrics).
* :class:`Observations`: flat (image index, point index, pixel) arrays; BA problems and the
  BAL / ParallaxBA / PVL-BA readers hold one.
* :func:`build_reconstruction`: flat arrays -> Reconstruction (the only such builder).
* :mod:`polarref.model.colmap`: Reconstruction <-> pycolmap, and pycolmap option builders.
* :class:`MethodRun` (:mod:`polarref.model.run`): the one record of a method's run;
  :class:`ReconstructionMetrics` (:mod:`polarref.model.scores`): the scores it embeds.
"""

from polarref.model.colmap import from_pycolmap, read_model, to_pycolmap
from polarref.model.observations import Observations, ObservationsError
from polarref.model.run import MethodRun, SkippedImage, TracePoint
from polarref.model.scores import ReconstructionMetrics
from polarref.model.reconstruction import Image, Point3D, Reconstruction, build_reconstruction

__all__ = ["Image", "MethodRun", "Observations", "ObservationsError", "Point3D", "Reconstruction",
           "ReconstructionMetrics", "SkippedImage", "TracePoint", "build_reconstruction", "from_pycolmap",
           "read_model", "to_pycolmap"]
