"""The vehicle's sensors: trajectory, cameras (pinhole + Brown-Conrady), scanner lattice."""
