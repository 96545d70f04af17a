"""Fleet data: raw logs like SBB's campaigns and the pipeline of the paper's Section III.A.

``trajectory`` (the :class:`Trajectory` type the predictors consume, Parquet I/O), ``formats``
(the campaigns' export formats and readers), ``fleetlogs`` (the seeded raw-log generator) and
``pipeline`` (clean, fuse, aggregate, segment, down-sample) and ``dataset`` (a raw directory
through the pipeline into Parquet files and ``dataset.json``).
"""

from trainclimate.data.trajectory import Trajectory, iter_trajectories, read_trajectories

__all__ = ["Trajectory", "iter_trajectories", "read_trajectories"]
