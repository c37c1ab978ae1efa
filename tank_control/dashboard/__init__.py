"""Live web dashboard of a running loop (docs/dashboard.md): trends of the signal topics,
parameter panels and controller commands, served by dashboard_node."""
