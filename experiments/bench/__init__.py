"""Speed against bare pybullet stepping (``scene-estimator bench``): the timing loop, the synthetic
scene, the scenarios' streams, ROS-bag input and the cost of recording."""
