"""ROS 1 and ROS 2 bags without a ROS install (``run --bag``): the topics file, the frame reader and
the estimate writer."""
