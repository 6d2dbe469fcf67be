# Source this on each PC, after scripts/env.sh, before starting nodes there (docs/multi-machine.md):
#   export VLA_PEER=192.168.50.2 VLA_DDS_INTERFACE=enp3s0
#   . <share>/vla_bringup/config/dds/two_hosts.sh
# VLA_PEER: the other PC's address. VLA_DDS_INTERFACE: this PC's interface that reaches it. Export
# them (`VAR=x . file` would not do: bash drops such assignments again when `.` returns).
# ROS_DOMAIN_ID must be the same on both PCs (it is left as it is: 0 when unset).
_vla_dds_dir=$(cd "$(dirname "${BASH_SOURCE[0]:-$0}")" && pwd)
if [ -z "${VLA_PEER:-}" ] || [ -z "${VLA_DDS_INTERFACE:-}" ]; then
    echo "two_hosts.sh: set VLA_PEER (the other PC's IP) and VLA_DDS_INTERFACE (this PC's NIC)" >&2
    return 2 2>/dev/null || exit 2
fi
if [ ! -e "/sys/class/net/$VLA_DDS_INTERFACE" ]; then
    echo "two_hosts.sh: no network interface '$VLA_DDS_INTERFACE' here (see: ip -br addr)" >&2
    return 2 2>/dev/null || exit 2
fi
export VLA_DDS_INTERFACE
export FASTRTPS_DEFAULT_PROFILES_FILE="$_vla_dds_dir/fastdds_two_hosts.xml"
export ROS_AUTOMATIC_DISCOVERY_RANGE=SUBNET   # multicast on the subnet, plus the static peer
export ROS_STATIC_PEERS="$VLA_PEER"           # unicast discovery: works where multicast is blocked
unset ROS_LOCALHOST_ONLY FASTDDS_BUILTIN_TRANSPORTS RMW_FASTRTPS_USE_QOS_FROM_XML
export RMW_IMPLEMENTATION=rmw_fastrtps_cpp
unset _vla_dds_dir
