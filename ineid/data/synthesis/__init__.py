"""Synthetic data: parameter sets and frames (:mod:`.sampling`), Fourier trajectories (:mod:`.trajectory`),
sensor noise (:mod:`.noise`), rehearsed IMUs (:mod:`.imu_rehearsal`), and the dataset generator
(:mod:`.generate`)."""
