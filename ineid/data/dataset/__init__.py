"""The HDF5 dataset format: its metadata (:mod:`.meta`), the in-memory :class:`~.schema.Dataset`, reading
(:mod:`.read`, after :mod:`.hdf5_audit` checks that the file reaches nothing outside itself) and writing
(:mod:`.write`, streamed and atomic). The format is described in ``docs/dataset.md``."""
