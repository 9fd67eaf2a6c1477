"""`prsm-bag`: reading, exporting, reporting on and replaying recorded ROS 2 MCAP bags."""
