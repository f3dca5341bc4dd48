"""The robot: model (URDF + tool), frames, closed-form and numeric inverse kinematics, path IK and the cell."""
