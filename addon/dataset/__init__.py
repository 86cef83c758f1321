"""Writing NeRF datasets: transforms files, the capture manifest, point clouds."""
