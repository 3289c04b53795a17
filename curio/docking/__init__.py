"""The charging dock: home and dock as one named pose, the dock's shape (seen by the lidar and
modelled by the simulator), and docking as a behaviour (staging, a slow final approach aligned
on the dock's shape, retries, undocking)."""
