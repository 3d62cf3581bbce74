# Sourced by the run scripts: the environment our ROS 2 processes run in.
# - AMENT_PREFIX_PATH: the venv is the ament prefix (nothing else sets it in a venv).
# - ROS_LOG_DIR: rcl writes a log file per process; keep them in the work tree.
# - ROS_DOMAIN_ID: a domain of its own per run unless the caller chose one, so that parallel runs
#   on one machine do not talk to each other. Tests derive per-test domains from it.
# - ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST: our graphs run on one machine.
# - FASTRTPS_DEFAULT_PROFILES_FILE: Fast DDS participants re-announce every 0.25 s (our nodes set
#   it themselves; exported here for the ros2 CLI too), unless a profile file was chosen.
_nmrm_root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
export NMRM_VENV="${NMRM_VENV:-$_nmrm_root/.venv}"
export AMENT_PREFIX_PATH="$NMRM_VENV${AMENT_PREFIX_PATH:+:$AMENT_PREFIX_PATH}"
export ROS_LOG_DIR="${ROS_LOG_DIR:-$_nmrm_root/build/ros_log}"
export ROS_DOMAIN_ID="${ROS_DOMAIN_ID:-$(( (RANDOM % 90) + 10 ))}"
export ROS_AUTOMATIC_DISCOVERY_RANGE="${ROS_AUTOMATIC_DISCOVERY_RANGE:-LOCALHOST}"
if [ -z "${FASTRTPS_DEFAULT_PROFILES_FILE:-}${FASTDDS_DEFAULT_PROFILES_FILE:-}" ]; then
  export FASTRTPS_DEFAULT_PROFILES_FILE="$_nmrm_root/config/fastdds_discovery.xml"
fi
export PATH="$NMRM_VENV/bin:$PATH"
unset _nmrm_root
