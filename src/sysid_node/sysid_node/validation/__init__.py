"""Model against measurement: residual tests, diagnosis of the missing physical effect,
augmentation and re-fit (pure numpy/scipy, no rclpy)."""
