# The venv as a ROS 2 underlay, like /opt/ros/<distro>/setup.sh on a robot: puts the venv's
# ROS 2 wheels (and ros2, colcon) on PATH and the venv on AMENT_PREFIX_PATH.
#
#   source .venv/setup.bash      # then: colcon build, ros2 launch, ros2 run ...
#
# make copies this file to .venv/setup.{sh,bash} and .venv/local_setup.{sh,bash} with
# @PREFIX@ replaced by the venv's absolute path. colcon finds local_setup.* in a prefix of
# AMENT_PREFIX_PATH and chains it into the workspace's install/setup.bash, as it does for
# /opt/ros/<distro>; a workspace's `source install/setup.bash` then needs nothing else.
_tc_prefix="@PREFIX@"
case ":${AMENT_PREFIX_PATH:-}:" in
  *":${_tc_prefix}:"*) ;;
  *) export AMENT_PREFIX_PATH="${_tc_prefix}${AMENT_PREFIX_PATH:+:${AMENT_PREFIX_PATH}}" ;;
esac
case ":${PATH:-}:" in
  *":${_tc_prefix}/bin:"*) ;;
  *) export PATH="${_tc_prefix}/bin${PATH:+:${PATH}}" ;;
esac
unset _tc_prefix
