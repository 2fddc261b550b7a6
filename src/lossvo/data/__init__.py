"""Datasets in the KITTI odometry layout: the KITTI reader and the synthetic renderer that writes one."""
