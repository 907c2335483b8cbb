"""Registration: mesh layer, pose search, rigid ICP, GB-CICP virtual fixturing and baselines.

Kept free of heavy imports (everything imports it): the submodules are imported by name --
:mod:`~qifreport.registration.mesh`, :mod:`~qifreport.registration.pointcloud`,
:mod:`~qifreport.registration.icp`, :mod:`~qifreport.registration.pose.prealign` (the pose search,
with :mod:`~qifreport.registration.pose.model`, :mod:`~qifreport.registration.pose.starts`,
:mod:`~qifreport.registration.pose.fit`, :mod:`~qifreport.registration.pose.basins` and
:mod:`~qifreport.registration.pose.geometry`), :mod:`~qifreport.registration.deformable.gbcicp`,
:mod:`~qifreport.registration.deformable.methods` and the baselines. Registration depends only on
:mod:`qifreport.errors` within the product.
"""

from qifreport.errors import InputError

__all__ = ["InputError"]
