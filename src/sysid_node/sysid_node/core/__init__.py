"""Pure numerics of the deterministic-stochastic realization algorithm (no rclpy)."""
