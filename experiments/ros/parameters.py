"""The options of ``scene-estimator ros`` that a ROS private parameter (``~name``) may set when the
command line does not (no ROS import: the command line reads it without rospy)."""

PARAMETERS = ("scene", "topics", "world_frame", "config", "particles", "workers", "seed", "horizon",
              "t_perceived", "d_sim_perc", "d_perc_prev", "reset_after", "silent_after", "timeline_window",
              "fixed_particles")
