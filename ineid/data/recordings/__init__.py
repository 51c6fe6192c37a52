"""A real arm's recording into a dataset: the streams as read (:mod:`.streams`) from a CSV
(:mod:`.csv_import`, :mod:`.csv_rows`) or a ROS bag (:mod:`.bags`, :mod:`.bag_metadata`), filtered and
differentiated (:mod:`.signals`), with its channels (:mod:`.channels`) and IMUs (:mod:`.imus`), checked
(:mod:`.limits`, :mod:`.plausibility`) and summarised (:mod:`.summary`), by :mod:`.pipeline`."""
