"""The solvers: ICP (numpy and torch), Open3D's ICP and global registration, FPFH correspondences and RANSAC, and one adapter per method of the table (``backends``)."""
