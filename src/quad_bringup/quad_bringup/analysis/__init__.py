"""What a flight says: its metrics and completion rule, the report and its figures, and what it says of the vehicle
(identify). No rclpy."""
