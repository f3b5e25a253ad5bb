#include "common/config/enum_names.hpp"

#include "common/config/config.hpp"

namespace deif {

namespace {

template <typename Enum>
const char* NameOf(Enum value) {
  for (const EnumName<Enum>& entry : EnumTable<Enum>()) {
    if (entry.value == value) return entry.name;
  }
  return "?";
}

}  // namespace

template <>
const std::vector<EnumName<ControlLawKind>>& EnumTable<ControlLawKind>() {
  static const std::vector<EnumName<ControlLawKind>> table = {
      {"midpoint", ControlLawKind::kMidpoint},
      {"voronoi", ControlLawKind::kVoronoi},
      {"stationary", ControlLawKind::kStationary}};
  return table;
}

template <>
const std::vector<EnumName<MotionModelKind>>& EnumTable<MotionModelKind>() {
  static const std::vector<EnumName<MotionModelKind>> table = {
      {"random_walk", MotionModelKind::kRandomWalk},
      {"constant_velocity", MotionModelKind::kConstantVelocity}};
  return table;
}

template <>
const std::vector<EnumName<TrajectoryKind>>& EnumTable<TrajectoryKind>() {
  static const std::vector<EnumName<TrajectoryKind>> table = {
      {"figure_eight", TrajectoryKind::kFigureEight},
      {"figure_eight_shifted", TrajectoryKind::kFigureEightShifted},
      {"circle", TrajectoryKind::kCircle},
      {"line", TrajectoryKind::kLine},
      {"static", TrajectoryKind::kStatic},
      {"random_walk", TrajectoryKind::kRandomWalk}};
  return table;
}

template <>
const std::vector<EnumName<StepMode>>& EnumTable<StepMode>() {
  static const std::vector<EnumName<StepMode>> table = {{"lockstep", StepMode::kLockStep},
                                                        {"realtime", StepMode::kRealTime}};
  return table;
}

template <>
const std::vector<EnumName<FaultAction>>& EnumTable<FaultAction>() {
  static const std::vector<EnumName<FaultAction>> table = {
      {"kill", FaultAction::kKill},
      {"stop", FaultAction::kStop},
      {"cont", FaultAction::kCont},
      {"restart_target", FaultAction::kRestartTarget}};
  return table;
}

template <>
const std::vector<EnumName<DiscoveryKind>>& EnumTable<DiscoveryKind>() {
  static const std::vector<EnumName<DiscoveryKind>> table = {
      {"simple", DiscoveryKind::kSimple}, {"server", DiscoveryKind::kServer}};
  return table;
}

template <>
const std::vector<EnumName<TransportKind>>& EnumTable<TransportKind>() {
  static const std::vector<EnumName<TransportKind>> table = {{"udp", TransportKind::kUdp},
                                                             {"shm", TransportKind::kShm}};
  return table;
}

template <>
const std::vector<EnumName<ExchangeKind>>& EnumTable<ExchangeKind>() {
  static const std::vector<EnumName<ExchangeKind>> table = {{"auto", ExchangeKind::kAuto},
                                                            {"all_to_all", ExchangeKind::kAllToAll},
                                                            {"tree", ExchangeKind::kTree}};
  return table;
}

template <>
const std::vector<EnumName<MembershipKind>>& EnumTable<MembershipKind>() {
  static const std::vector<EnumName<MembershipKind>> table = {{"auto", MembershipKind::kAuto},
                                                              {"all_pairs", MembershipKind::kAllPairs},
                                                              {"roll_call", MembershipKind::kRollCall}};
  return table;
}

const char* ToString(ControlLawKind law) { return NameOf(law); }
const char* ToString(MotionModelKind kind) { return NameOf(kind); }
const char* ToString(TrajectoryKind kind) { return NameOf(kind); }
const char* ToString(StepMode mode) { return NameOf(mode); }
const char* ToString(FaultAction action) { return NameOf(action); }
const char* ToString(DiscoveryKind kind) { return NameOf(kind); }
const char* ToString(TransportKind kind) { return NameOf(kind); }
const char* ToString(ExchangeKind kind) { return NameOf(kind); }
const char* ToString(MembershipKind kind) { return NameOf(kind); }

}  // namespace deif
