"""Registration: mesh layer, pose search, rigid ICP, GB-CICP virtual fixturing and baselines.

Kept free of heavy imports (everything imports it): the submodules are imported by name --
:mod:`~qifreport.registration.mesh`, :mod:`~qifreport.registration.pointcloud`,
:mod:`~qifreport.registration.icp`, :mod:`~qifreport.registration.prealign` (the pose search,
with :mod:`~qifreport.registration.pose_model`, :mod:`~qifreport.registration.pose_starts`,
:mod:`~qifreport.registration.pose_fit`, :mod:`~qifreport.registration.basins` and
:mod:`~qifreport.registration.pose_geometry`), :mod:`~qifreport.registration.gbcicp`,
:mod:`~qifreport.registration.methods` and the baselines. Registration depends only on
:mod:`qifreport.errors` within the product.
"""

from qifreport.errors import InputError

__all__ = ["InputError"]
