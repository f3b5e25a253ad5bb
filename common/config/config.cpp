// YAML -> Config, one function per section (see configs/default.yaml for every key).
//
// Every error is a ConfigError naming the file, the dotted key and the line, so that the
// executables can print one clear line and stop before starting anything.
#include "common/config/config.hpp"

#include <yaml-cpp/yaml.h>

#include <algorithm>
#include <cerrno>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <fstream>
#include <limits>
#include <map>
#include <optional>
#include <set>
#include <sstream>
#include <utility>

namespace deif {

namespace {

constexpr double kTwoPi = 6.283185307179586476925286766559;

// The shortest decimal text that reads back to the same double (YAML spelling of inf).
std::string FormatDoubleShort(double value) {
  if (std::isinf(value)) return value > 0 ? ".inf" : "-.inf";
  if (std::isnan(value)) return ".nan";
  char buffer[40];
  if (value == std::floor(value) && std::abs(value) < 1e15) {
    std::snprintf(buffer, sizeof(buffer), "%.0f", value);  // 30, not 3e+01
    return buffer;
  }
  for (int precision = 1; precision <= 17; ++precision) {
    std::snprintf(buffer, sizeof(buffer), "%.*g", precision, value);
    if (std::strtod(buffer, nullptr) == value) break;
  }
  return buffer;
}


std::string BuildMessage(const std::string& file, const std::string& key, int line,
                         const std::string& reason) {
  std::string message = file.empty() ? std::string("<config>") : file;
  if (line > 0) message += ":" + std::to_string(line);
  message += ": ";
  if (!key.empty()) message += "key '" + key + "': ";
  message += reason;
  return message;
}

// ---------------------------------------------------------------------------------------
// Low-level readers. Each takes the node, the dotted key naming it, and the context.

struct ParseContext {
  std::string file;  // what messages call the file
};

int LineOf(const YAML::Node& node) {
  if (!node.IsDefined()) return 0;
  const YAML::Mark mark = node.Mark();
  return mark.is_null() ? 0 : mark.line + 1;
}

[[noreturn]] void Fail(const ParseContext& ctx, const std::string& key, const YAML::Node& node,
                       const std::string& reason) {
  throw ConfigError(ctx.file, key, LineOf(node), reason);
}

std::string Describe(const YAML::Node& node) {
  switch (node.Type()) {
    case YAML::NodeType::Null:
      return "nothing (null)";
    case YAML::NodeType::Sequence:
      return "a list";
    case YAML::NodeType::Map:
      return "a mapping";
    case YAML::NodeType::Scalar:
      return node.Tag() == "!" ? "the quoted string '" + node.Scalar() + "'"
                               : "'" + node.Scalar() + "'";
    case YAML::NodeType::Undefined:
      break;
  }
  return "nothing";
}

std::string JoinNames(const std::vector<std::string>& names) {
  std::string out;
  for (const auto& name : names) {
    if (!out.empty()) out += ", ";
    out += name;
  }
  return out;
}

// The scalar text of a plain (unquoted) scalar that should hold a number.
const std::string& NumberText(const ParseContext& ctx, const std::string& key,
                              const YAML::Node& node, const char* what) {
  if (!node.IsScalar() || node.Tag() == "!") {
    Fail(ctx, key, node, std::string("expected ") + what + " (got " + Describe(node) + ")");
  }
  return node.Scalar();
}

double ReadDouble(const ParseContext& ctx, const std::string& key, const YAML::Node& node,
                  bool allow_infinity = false) {
  const std::string& text = NumberText(ctx, key, node, "a number");
  double value = 0.0;
  if (text == ".inf" || text == ".Inf" || text == ".INF" || text == "+.inf" ||
      text == "+.Inf" || text == "+.INF") {
    value = std::numeric_limits<double>::infinity();
  } else if (text == "-.inf" || text == "-.Inf" || text == "-.INF") {
    value = -std::numeric_limits<double>::infinity();
  } else if (text == ".nan" || text == ".NaN" || text == ".NAN") {
    value = std::numeric_limits<double>::quiet_NaN();
  } else {
    // strtod would also take "inf", "nan" and hex floats; YAML numbers are decimal.
    const bool decimal = !text.empty() && text.find_first_not_of("0123456789+-.eE") ==
                                              std::string::npos;
    char* end = nullptr;
    errno = 0;
    value = decimal ? std::strtod(text.c_str(), &end) : 0.0;
    if (!decimal || end != text.c_str() + text.size() || errno == ERANGE) {
      Fail(ctx, key, node, "expected a number (got " + Describe(node) + ")");
    }
  }
  if (std::isnan(value) || (std::isinf(value) && !(allow_infinity && value > 0))) {
    Fail(ctx, key, node,
         std::string("must be a finite number") + (allow_infinity ? " or .inf" : "") +
             " (got " + text + ")");
  }
  return value;
}

std::int64_t ReadInt64(const ParseContext& ctx, const std::string& key, const YAML::Node& node) {
  const std::string& text = NumberText(ctx, key, node, "an integer");
  const bool digits = !text.empty() &&
                      text.find_first_not_of("0123456789", text[0] == '-' || text[0] == '+'
                                                               ? 1U
                                                               : 0U) == std::string::npos &&
                      text.size() > (text[0] == '-' || text[0] == '+' ? 1U : 0U);
  char* end = nullptr;
  errno = 0;
  const long long value = digits ? std::strtoll(text.c_str(), &end, 10) : 0;
  if (!digits || end != text.c_str() + text.size() || errno == ERANGE) {
    Fail(ctx, key, node, "expected an integer (got " + Describe(node) + ")");
  }
  return static_cast<std::int64_t>(value);
}

int ReadInt(const ParseContext& ctx, const std::string& key, const YAML::Node& node) {
  const std::int64_t value = ReadInt64(ctx, key, node);
  if (value < std::numeric_limits<int>::min() || value > std::numeric_limits<int>::max()) {
    Fail(ctx, key, node, "integer out of range (got " + node.Scalar() + ")");
  }
  return static_cast<int>(value);
}

std::uint64_t ReadUint64(const ParseContext& ctx, const std::string& key,
                         const YAML::Node& node) {
  const std::string& text = NumberText(ctx, key, node, "a non-negative integer");
  const bool digits = !text.empty() && text.find_first_not_of("0123456789") == std::string::npos;
  char* end = nullptr;
  errno = 0;
  const unsigned long long value = digits ? std::strtoull(text.c_str(), &end, 10) : 0;
  if (!digits || end != text.c_str() + text.size() || errno == ERANGE) {
    Fail(ctx, key, node,
         "expected a non-negative integer below 2^64 (got " + Describe(node) + ")");
  }
  return static_cast<std::uint64_t>(value);
}

std::string ReadString(const ParseContext& ctx, const std::string& key, const YAML::Node& node) {
  if (!node.IsScalar()) Fail(ctx, key, node, "expected a string (got " + Describe(node) + ")");
  return node.Scalar();
}

std::vector<double> ReadDoubleList(const ParseContext& ctx, const std::string& key,
                                   const YAML::Node& node) {
  if (!node.IsSequence()) {
    Fail(ctx, key, node, "expected a list of numbers (got " + Describe(node) + ")");
  }
  std::vector<double> values;
  for (std::size_t i = 0; i < node.size(); ++i) {
    values.push_back(ReadDouble(ctx, key + "[" + std::to_string(i) + "]", node[i]));
  }
  return values;
}

Vector2 ReadVector2(const ParseContext& ctx, const std::string& key, const YAML::Node& node) {
  if (!node.IsSequence() || node.size() != 2) {
    Fail(ctx, key, node,
         "expected a list of two numbers [x, y] (got " +
             (node.IsSequence() ? "a list of " + std::to_string(node.size())
                                : Describe(node)) +
             ")");
  }
  return Vector2(ReadDouble(ctx, key + "[0]", node[0]), ReadDouble(ctx, key + "[1]", node[1]));
}

template <typename Enum>
struct EnumName {
  const char* name;
  Enum value;
};

template <typename Enum, std::size_t N>
Enum ReadEnum(const ParseContext& ctx, const std::string& key, const YAML::Node& node,
              const EnumName<Enum> (&table)[N]) {
  std::vector<std::string> allowed;
  for (const auto& entry : table) allowed.emplace_back(entry.name);
  if (!node.IsScalar()) {
    Fail(ctx, key, node,
         "expected one of " + JoinNames(allowed) + " (got " + Describe(node) + ")");
  }
  for (const auto& entry : table) {
    if (node.Scalar() == entry.name) return entry.value;
  }
  Fail(ctx, key, node,
       "unknown value '" + node.Scalar() + "'; allowed: " + JoinNames(allowed));
}

template <typename Enum, std::size_t N>
const char* EnumToString(Enum value, const EnumName<Enum> (&table)[N]) {
  for (const auto& entry : table) {
    if (entry.value == value) return entry.name;
  }
  return "?";
}

const EnumName<StepMode> kStepModes[] = {{"lockstep", StepMode::kLockStep},
                                         {"realtime", StepMode::kRealTime}};
const EnumName<TrajectoryKind> kTrajectories[] = {
    {"figure_eight", TrajectoryKind::kFigureEight},
    {"figure_eight_shifted", TrajectoryKind::kFigureEightShifted},
    {"circle", TrajectoryKind::kCircle},
    {"line", TrajectoryKind::kLine},
    {"static", TrajectoryKind::kStatic},
    {"random_walk", TrajectoryKind::kRandomWalk}};
const EnumName<MotionModelKind> kMotionModels[] = {
    {"random_walk", MotionModelKind::kRandomWalk},
    {"constant_velocity", MotionModelKind::kConstantVelocity}};
const EnumName<ControlLawKind> kControlLaws[] = {{"midpoint", ControlLawKind::kMidpoint},
                                                 {"voronoi", ControlLawKind::kVoronoi},
                                                 {"stationary", ControlLawKind::kStationary}};
const EnumName<FaultAction> kFaultActions[] = {{"kill", FaultAction::kKill},
                                               {"stop", FaultAction::kStop},
                                               {"cont", FaultAction::kCont},
                                               {"restart_target", FaultAction::kRestartTarget}};

// ---------------------------------------------------------------------------------------
// A mapping with a fixed set of allowed keys. Construction rejects anything else: a
// non-mapping, an unknown key (naming the allowed ones) or a duplicate key.
class Section {
 public:
  Section(const ParseContext& ctx, const YAML::Node& node, std::string path,
          std::vector<std::string> allowed)
      : ctx_(ctx), node_(node), path_(std::move(path)), allowed_(std::move(allowed)) {
    if (!node_.IsDefined() || node_.IsNull()) return;  // absent or empty: all defaults
    if (!node_.IsMap()) {
      Fail(ctx_, path_, node_, "expected a mapping of keys (got " + Describe(node_) + ")");
    }
    std::set<std::string> seen;
    for (const auto& entry : node_) {
      const YAML::Node& key_node = entry.first;
      if (!key_node.IsScalar()) Fail(ctx_, path_, key_node, "keys must be plain names");
      const std::string& name = key_node.Scalar();
      if (std::find(allowed_.begin(), allowed_.end(), name) == allowed_.end()) {
        Fail(ctx_, Key(name), key_node, "unknown key; allowed: " + JoinNames(allowed_));
      }
      if (!seen.insert(name).second) Fail(ctx_, Key(name), key_node, "duplicate key");
    }
  }

  bool Has(const std::string& name) const {
    return node_.IsDefined() && node_.IsMap() && node_[name].IsDefined();
  }
  // The value of a key, or a null node when it is absent.
  YAML::Node Get(const std::string& name) const { return Has(name) ? node_[name] : YAML::Node(); }
  std::string Key(const std::string& name) const {
    return path_.empty() ? name : path_ + "." + name;
  }
  const YAML::Node& node() const { return node_; }

 private:
  const ParseContext& ctx_;
  const YAML::Node node_;
  std::string path_;
  std::vector<std::string> allowed_;
};

// Reads an optional key into `value` (left at its default when absent) and returns whether
// it was present.
template <typename Reader>
auto Optional(const Section& section, const std::string& name, Reader reader)
    -> std::optional<decltype(reader(std::string(), YAML::Node()))> {
  if (!section.Has(name)) return std::nullopt;
  return reader(section.Key(name), section.Get(name));
}

// Range checks, each naming the key, the rule and the value.
void RequirePositive(const ParseContext& ctx, const Section& s, const std::string& name,
                     double value) {
  if (!(value > 0.0)) {
    Fail(ctx, s.Key(name), s.Get(name), "must be > 0 (got " + s.Get(name).Scalar() + ")");
  }
}
void RequireNonNegative(const ParseContext& ctx, const Section& s, const std::string& name,
                        double value) {
  if (!(value >= 0.0)) {
    Fail(ctx, s.Key(name), s.Get(name), "must be >= 0 (got " + s.Get(name).Scalar() + ")");
  }
}

// An optional key that must be > 0 (or >= 0): when present, checked and stored in field.
template <typename Reader>
void ReadPositive(const ParseContext& ctx, const Section& s, const std::string& name,
                  Reader reader, double& field) {
  if (auto v = Optional(s, name, reader)) {
    RequirePositive(ctx, s, name, *v);
    field = *v;
  }
}
template <typename Reader>
void ReadNonNegative(const ParseContext& ctx, const Section& s, const std::string& name,
                     Reader reader, double& field) {
  if (auto v = Optional(s, name, reader)) {
    RequireNonNegative(ctx, s, name, *v);
    field = *v;
  }
}

// ---------------------------------------------------------------------------------------
// One function per section.

ScenarioConfig ParseScenario(const YAML::Node& node, const ParseContext& ctx) {
  const Section s(ctx, node, "scenario", {"name", "seed", "steps", "dt_s", "mode", "period_s"});
  ScenarioConfig out;
  const auto num = [&](const std::string& key, const YAML::Node& n) {
    return ReadDouble(ctx, key, n);
  };
  if (auto v = Optional(s, "name", [&](const std::string& key, const YAML::Node& n) {
        return ReadString(ctx, key, n);
      })) {
    if (v->empty()) Fail(ctx, s.Key("name"), s.Get("name"), "must not be empty");
    out.name = *v;
  }
  if (auto v = Optional(s, "seed", [&](const std::string& key, const YAML::Node& n) {
        return ReadUint64(ctx, key, n);
      })) {
    out.seed = *v;
  }
  if (auto v = Optional(s, "steps", [&](const std::string& key, const YAML::Node& n) {
        return ReadInt64(ctx, key, n);
      })) {
    if (*v < 1) Fail(ctx, s.Key("steps"), s.Get("steps"), "must be >= 1 (got " + s.Get("steps").Scalar() + ")");
    out.steps = *v;
  }
  ReadPositive(ctx, s, "dt_s", num, out.dt_s);
  if (auto v = Optional(s, "mode", [&](const std::string& key, const YAML::Node& n) {
        return ReadEnum(ctx, key, n, kStepModes);
      })) {
    out.mode = *v;
  }
  ReadPositive(ctx, s, "period_s", num, out.period_s);
  return out;
}

TargetConfig ParseTarget(const YAML::Node& node, const ParseContext& ctx) {
  const Section s(ctx, node, "target",
                  {"trajectory", "start_m", "velocity_mps", "circle_radius_m",
                   "angular_rate_radps", "process_noise_variance_m2", "range_noise_variance_m2"});
  TargetConfig out;
  TrajectoryConfig& traj = out.trajectory;
  const auto num = [&](const std::string& key, const YAML::Node& n) {
    return ReadDouble(ctx, key, n);
  };
  const auto vec = [&](const std::string& key, const YAML::Node& n) {
    return ReadVector2(ctx, key, n);
  };
  if (auto v = Optional(s, "trajectory", [&](const std::string& key, const YAML::Node& n) {
        return ReadEnum(ctx, key, n, kTrajectories);
      })) {
    traj.kind = *v;
  }
  if (auto v = Optional(s, "start_m", vec)) traj.start_m = *v;
  if (auto v = Optional(s, "velocity_mps", vec)) traj.velocity_mps = *v;
  if (auto v = Optional(s, "circle_radius_m", num)) {
    RequirePositive(ctx, s, "circle_radius_m", *v);
    traj.circle_radius_m = *v;
  }
  if (auto v = Optional(s, "angular_rate_radps", num)) traj.angular_rate_radps = *v;
  if (auto v = Optional(s, "process_noise_variance_m2", num)) {
    RequireNonNegative(ctx, s, "process_noise_variance_m2", *v);
    traj.process_noise_variance = *v;
  }
  ReadPositive(ctx, s, "range_noise_variance_m2", num, out.range_noise_variance_m2);
  return out;
}

FilterConfig ParseFilter(const YAML::Node& node, const ParseContext& ctx, double dt_s) {
  const Section s(ctx, node, "filter",
                  {"motion_model", "process_noise", "range_variance_m2", "initial_estimate_m",
                   "initial_position_variance_m2", "initial_velocity_variance_m2ps2"});
  FilterConfig out;
  out.motion_model.dt_s = dt_s;
  const auto num = [&](const std::string& key, const YAML::Node& n) {
    return ReadDouble(ctx, key, n);
  };
  if (auto v = Optional(s, "motion_model", [&](const std::string& key, const YAML::Node& n) {
        return ReadEnum(ctx, key, n, kMotionModels);
      })) {
    out.motion_model.kind = *v;
  }
  ReadPositive(ctx, s, "process_noise", num, out.motion_model.process_noise);
  ReadPositive(ctx, s, "range_variance_m2", num, out.range_variance_m2);
  if (auto v = Optional(s, "initial_estimate_m", [&](const std::string& key, const YAML::Node& n) {
        return ReadVector2(ctx, key, n);
      })) {
    out.initial_estimate_m = *v;
  }
  ReadPositive(ctx, s, "initial_position_variance_m2", num, out.initial_position_variance_m2);
  ReadPositive(ctx, s, "initial_velocity_variance_m2ps2", num, out.initial_velocity_variance_m2ps2);
  return out;
}

SensingFunction ParseSensing(const YAML::Node& node, const ParseContext& ctx) {
  const Section s(ctx, node, "sensing", {"c0", "r0_m", "r1_m", "beta"});
  SensingFunction out;
  const auto num = [&](const std::string& key, const YAML::Node& n) {
    return ReadDouble(ctx, key, n);
  };
  if (auto v = Optional(s, "c0", num)) out.c0 = *v;
  ReadNonNegative(ctx, s, "r0_m", num, out.r0_m);
  if (auto v = Optional(s, "r1_m", [&](const std::string& key, const YAML::Node& n) {
        return ReadDouble(ctx, key, n, /*allow_infinity=*/true);
      })) {
    out.r1_m = *v;
  }
  if (!(out.r1_m > out.r0_m)) {
    const std::string name = s.Has("r1_m") ? "r1_m" : "r0_m";
    Fail(ctx, s.Key(name), s.Get(name),
         "r1_m must be > r0_m (got r0_m " + FormatDoubleShort(out.r0_m) + ", r1_m " +
             FormatDoubleShort(out.r1_m) + ")");
  }
  if (s.Has("beta")) {
    const YAML::Node n = s.Get("beta");
    std::int64_t beta = 0;
    try {
      beta = ReadInt64(ctx, s.Key("beta"), n);
    } catch (const ConfigError&) {
      Fail(ctx, s.Key("beta"), n,
           "must be a positive integer or -1 (got " + Describe(n) + ")");
    }
    if (beta < 1 && beta != -1) {
      Fail(ctx, s.Key("beta"), n, "must be a positive integer or -1 (got " + n.Scalar() + ")");
    }
    if (beta > 64) Fail(ctx, s.Key("beta"), n, "must be <= 64 (got " + n.Scalar() + ")");
    out.beta = static_cast<double>(beta);
  }
  return out;
}

AgentsConfig ParseAgents(const YAML::Node& node, const ParseContext& ctx) {
  const Section s(ctx, node, "agents",
                  {"count", "initial_angles_rad", "initial_centre_m", "radius_m",
                   "max_speed_mps", "control_law"});
  AgentsConfig out;
  const auto num = [&](const std::string& key, const YAML::Node& n) {
    return ReadDouble(ctx, key, n);
  };
  if (auto v = Optional(s, "count", [&](const std::string& key, const YAML::Node& n) {
        return ReadInt(ctx, key, n);
      })) {
    if (*v < 2) Fail(ctx, s.Key("count"), s.Get("count"), "must be >= 2 (got " + s.Get("count").Scalar() + ")");
    out.count = *v;
  }
  if (auto v = Optional(s, "initial_angles_rad", [&](const std::string& key, const YAML::Node& n) {
        return ReadDoubleList(ctx, key, n);
      })) {
    if (static_cast<int>(v->size()) != out.count) {
      Fail(ctx, s.Key("initial_angles_rad"), s.Get("initial_angles_rad"),
           "must have one angle per agent: length must equal agents.count = " +
               std::to_string(out.count) + " (got " + std::to_string(v->size()) + ")");
    }
    out.initial_angles_rad = *v;
  }
  if (auto v = Optional(s, "initial_centre_m", [&](const std::string& key, const YAML::Node& n) {
        return ReadVector2(ctx, key, n);
      })) {
    out.initial_centre_m = *v;
  }
  ReadPositive(ctx, s, "radius_m", num, out.radius_m);
  ReadNonNegative(ctx, s, "max_speed_mps", num, out.max_speed_mps);
  if (auto v = Optional(s, "control_law", [&](const std::string& key, const YAML::Node& n) {
        return ReadEnum(ctx, key, n, kControlLaws);
      })) {
    out.control_law = *v;
  }
  return out;
}

NetworkConfig ParseNetwork(const YAML::Node& node, const ParseContext& ctx) {
  const Section s(ctx, node, "network",
                  {"domain_id", "liveliness_lease_s", "participant_lease_s",
                   "participant_announcement_s", "step_timeout_s", "start_timeout_s",
                   "fusion_window_steps"});
  NetworkConfig out;
  const auto num = [&](const std::string& key, const YAML::Node& n) {
    return ReadDouble(ctx, key, n);
  };
  const auto integer = [&](const std::string& key, const YAML::Node& n) {
    return ReadInt(ctx, key, n);
  };
  if (auto v = Optional(s, "domain_id", integer)) {
    // Fast DDS calls exit() for domain ids above 232 (docs/PITFALLS).
    if (*v < 0 || *v > 232) {
      Fail(ctx, s.Key("domain_id"), s.Get("domain_id"),
           "must be in 0..232 (got " + s.Get("domain_id").Scalar() + ")");
    }
    out.domain_id = *v;
  }
  ReadPositive(ctx, s, "liveliness_lease_s", num, out.liveliness_lease_s);
  ReadPositive(ctx, s, "participant_lease_s", num, out.participant_lease_s);
  ReadPositive(ctx, s, "participant_announcement_s", num, out.participant_announcement_s);
  if (!(out.participant_announcement_s < out.participant_lease_s)) {
    const std::string name =
        s.Has("participant_announcement_s") ? "participant_announcement_s" : "participant_lease_s";
    Fail(ctx, s.Key(name), s.Get(name),
         "participant_announcement_s must be < participant_lease_s (got " +
             FormatDoubleShort(out.participant_announcement_s) + " >= " +
             FormatDoubleShort(out.participant_lease_s) + ")");
  }
  ReadPositive(ctx, s, "step_timeout_s", num, out.step_timeout_s);
  ReadPositive(ctx, s, "start_timeout_s", num, out.start_timeout_s);
  if (auto v = Optional(s, "fusion_window_steps", integer)) {
    if (*v < 0) {
      Fail(ctx, s.Key("fusion_window_steps"), s.Get("fusion_window_steps"),
           "must be >= 0 (got " + s.Get("fusion_window_steps").Scalar() + ")");
    }
    out.fusion_window_steps = *v;
  }
  return out;
}

// Faults need the number of steps and agents to check their step and agent id, and are
// checked as a sequence: nothing happens to a killed agent, cont only follows stop.
std::vector<FaultConfig> ParseFaults(const YAML::Node& node, const ParseContext& ctx,
                                     const ScenarioConfig& scenario, const AgentsConfig& agents) {
  std::vector<FaultConfig> out;
  if (!node.IsDefined() || node.IsNull()) return out;
  if (!node.IsSequence()) {
    Fail(ctx, "faults", node,
         "expected a list of {step, action, agent} (got " + Describe(node) + ")");
  }
  std::vector<YAML::Node> nodes;
  for (std::size_t i = 0; i < node.size(); ++i) {
    const std::string path = "faults[" + std::to_string(i) + "]";
    const YAML::Node entry = node[i];
    if (!entry.IsMap()) {
      Fail(ctx, path, entry, "expected a mapping {step, action, agent} (got " + Describe(entry) + ")");
    }
    const Section s(ctx, entry, path, {"step", "action", "agent"});
    FaultConfig fault;
    if (!s.Has("step")) Fail(ctx, s.Key("step"), entry, "missing (every fault needs a step)");
    if (!s.Has("action")) Fail(ctx, s.Key("action"), entry, "missing (every fault needs an action)");
    fault.step = ReadInt64(ctx, s.Key("step"), s.Get("step"));
    if (fault.step < 1 || fault.step > scenario.steps) {
      Fail(ctx, s.Key("step"), s.Get("step"),
           "must be in 1..scenario.steps = 1.." + std::to_string(scenario.steps) + " (got " +
               s.Get("step").Scalar() + ")");
    }
    fault.action = ReadEnum(ctx, s.Key("action"), s.Get("action"), kFaultActions);
    if (fault.action == FaultAction::kRestartTarget) {
      if (s.Has("agent")) {
        Fail(ctx, s.Key("agent"), s.Get("agent"), "restart_target takes no agent");
      }
    } else {
      if (!s.Has("agent")) {
        Fail(ctx, s.Key("agent"), entry,
             std::string("missing (action ") + EnumToString(fault.action, kFaultActions) +
                 " needs an agent id)");
      }
      fault.agent_id = ReadInt(ctx, s.Key("agent"), s.Get("agent"));
      if (fault.agent_id < 1 || fault.agent_id > agents.count) {
        Fail(ctx, s.Key("agent"), s.Get("agent"),
             "agent id must be in 1.." + std::to_string(agents.count) + " (got " +
                 s.Get("agent").Scalar() + ")");
      }
    }
    out.push_back(fault);
    nodes.push_back(entry);
  }

  // The faults as a sequence in step order (file order within a step).
  std::vector<std::size_t> order(out.size());
  for (std::size_t i = 0; i < order.size(); ++i) order[i] = i;
  std::stable_sort(order.begin(), order.end(),
                   [&](std::size_t a, std::size_t b) { return out[a].step < out[b].step; });
  enum class State { kRunning, kStopped, kKilled };
  std::map<AgentId, State> state;
  int killed = 0;
  for (const std::size_t i : order) {
    const FaultConfig& f = out[i];
    if (f.action == FaultAction::kRestartTarget) continue;
    const std::string key = "faults[" + std::to_string(i) + "].action";
    State& st = state[f.agent_id];
    const std::string who = "agent " + std::to_string(f.agent_id);
    if (st == State::kKilled) {
      Fail(ctx, key, nodes[i]["action"], who + " was already killed before step " + std::to_string(f.step));
    }
    switch (f.action) {
      case FaultAction::kKill:
        st = State::kKilled;
        ++killed;
        break;
      case FaultAction::kStop:
        if (st == State::kStopped) Fail(ctx, key, nodes[i]["action"], who + " is already stopped");
        st = State::kStopped;
        break;
      case FaultAction::kCont:
        if (st != State::kStopped) {
          Fail(ctx, key, nodes[i]["action"], "cont needs an earlier stop of " + who);
        }
        st = State::kRunning;
        break;
      case FaultAction::kRestartTarget:
        break;
    }
  }
  if (killed >= agents.count) {
    Fail(ctx, "faults", node, "the faults kill every agent; at least one must survive");
  }
  return out;
}

Config ParseRoot(const YAML::Node& root, const std::string& source_name) {
  const ParseContext ctx{source_name};
  const Section top(ctx, root, "",
                    {"scenario", "target", "filter", "sensing", "agents", "network", "faults"});
  Config config;
  config.source = source_name;
  config.scenario = ParseScenario(top.Get("scenario"), ctx);
  config.target = ParseTarget(top.Get("target"), ctx);
  config.filter = ParseFilter(top.Get("filter"), ctx, config.scenario.dt_s);
  config.sensing = ParseSensing(top.Get("sensing"), ctx);
  config.agents = ParseAgents(top.Get("agents"), ctx);
  config.network = ParseNetwork(top.Get("network"), ctx);
  config.faults = ParseFaults(top.Get("faults"), ctx, config.scenario, config.agents);
  return config;
}

}  // namespace

// ---------------------------------------------------------------------------------------

ConfigError::ConfigError(std::string file, std::string key, int line, const std::string& reason)
    : std::runtime_error(BuildMessage(file, key, line, reason)),
      file_(std::move(file)),
      key_(std::move(key)),
      line_(line) {}

Config ParseConfig(const std::string& yaml_text, const std::string& source_name) {
  YAML::Node root;
  try {
    root = YAML::Load(yaml_text);
  } catch (const YAML::ParserException& e) {
    throw ConfigError(source_name, "", e.mark.is_null() ? 0 : e.mark.line + 1,
                      "YAML syntax error: " + e.msg);
  }
  return ParseRoot(root, source_name);
}

Config LoadConfig(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  if (!in) throw ConfigError(path, "", 0, "cannot open the config file");
  std::ostringstream text;
  text << in.rdbuf();
  if (in.bad()) throw ConfigError(path, "", 0, "cannot read the config file");
  return ParseConfig(text.str(), path);
}

namespace {

std::string YamlVector(const Vector2& v) {
  return "[" + FormatDoubleShort(v.x()) + ", " + FormatDoubleShort(v.y()) + "]";
}

std::string YamlQuoted(const std::string& text) {
  std::string out = "\"";
  for (const char c : text) {
    if (c == '"' || c == '\\') {
      out += '\\';
      out += c;
    } else if (static_cast<unsigned char>(c) < 0x20) {
      char buffer[8];
      std::snprintf(buffer, sizeof(buffer), "\\x%02x", static_cast<unsigned>(static_cast<unsigned char>(c)));
      out += buffer;
    } else {
      out += c;
    }
  }
  return out + "\"";
}

}  // namespace

std::string ToYaml(const Config& config) {
  std::ostringstream y;
  const auto d = [](double v) { return FormatDoubleShort(v); };
  y << "scenario:\n"
    << "  name: " << YamlQuoted(config.scenario.name) << "\n"
    << "  seed: " << config.scenario.seed << "\n"
    << "  steps: " << config.scenario.steps << "\n"
    << "  dt_s: " << d(config.scenario.dt_s) << "\n"
    << "  mode: " << ToString(config.scenario.mode) << "\n"
    << "  period_s: " << d(config.scenario.period_s) << "\n";
  const TrajectoryConfig& traj = config.target.trajectory;
  y << "target:\n"
    << "  trajectory: " << ToString(traj.kind) << "\n"
    << "  start_m: " << YamlVector(traj.start_m) << "\n"
    << "  velocity_mps: " << YamlVector(traj.velocity_mps) << "\n"
    << "  circle_radius_m: " << d(traj.circle_radius_m) << "\n"
    << "  angular_rate_radps: " << d(traj.angular_rate_radps) << "\n"
    << "  process_noise_variance_m2: " << d(traj.process_noise_variance) << "\n"
    << "  range_noise_variance_m2: " << d(config.target.range_noise_variance_m2) << "\n";
  y << "filter:\n"
    << "  motion_model: " << ToString(config.filter.motion_model.kind) << "\n"
    << "  process_noise: " << d(config.filter.motion_model.process_noise) << "\n"
    << "  range_variance_m2: " << d(config.filter.range_variance_m2) << "\n"
    << "  initial_estimate_m: " << YamlVector(config.filter.initial_estimate_m) << "\n"
    << "  initial_position_variance_m2: " << d(config.filter.initial_position_variance_m2)
    << "\n"
    << "  initial_velocity_variance_m2ps2: "
    << d(config.filter.initial_velocity_variance_m2ps2) << "\n";
  y << "sensing:\n"
    << "  c0: " << d(config.sensing.c0) << "\n"
    << "  r0_m: " << d(config.sensing.r0_m) << "\n"
    << "  r1_m: " << d(config.sensing.r1_m) << "\n"
    << "  beta: " << static_cast<long long>(config.sensing.beta) << "\n";
  y << "agents:\n" << "  count: " << config.agents.count << "\n";
  if (!config.agents.initial_angles_rad.empty()) {
    y << "  initial_angles_rad: [";
    for (std::size_t i = 0; i < config.agents.initial_angles_rad.size(); ++i) {
      y << (i ? ", " : "") << d(config.agents.initial_angles_rad[i]);
    }
    y << "]\n";
  }
  y << "  initial_centre_m: " << YamlVector(config.agents.initial_centre_m) << "\n"
    << "  radius_m: " << d(config.agents.radius_m) << "\n"
    << "  max_speed_mps: " << d(config.agents.max_speed_mps) << "\n"
    << "  control_law: " << ToString(config.agents.control_law) << "\n";
  const NetworkConfig& net = config.network;
  y << "network:\n"
    << "  domain_id: " << net.domain_id << "\n"
    << "  liveliness_lease_s: " << d(net.liveliness_lease_s) << "\n"
    << "  participant_lease_s: " << d(net.participant_lease_s) << "\n"
    << "  participant_announcement_s: " << d(net.participant_announcement_s) << "\n"
    << "  step_timeout_s: " << d(net.step_timeout_s) << "\n"
    << "  start_timeout_s: " << d(net.start_timeout_s) << "\n"
    << "  fusion_window_steps: " << net.fusion_window_steps << "\n";
  if (config.faults.empty()) {
    y << "faults: []\n";
  } else {
    y << "faults:\n";
    for (const FaultConfig& f : config.faults) {
      y << "  - {step: " << f.step << ", action: " << ToString(f.action);
      if (f.action != FaultAction::kRestartTarget) y << ", agent: " << f.agent_id;
      y << "}\n";
    }
  }
  return y.str();
}

const char* ToString(ControlLawKind law) { return EnumToString(law, kControlLaws); }
const char* ToString(MotionModelKind kind) { return EnumToString(kind, kMotionModels); }
const char* ToString(TrajectoryKind kind) { return EnumToString(kind, kTrajectories); }
const char* ToString(StepMode mode) { return EnumToString(mode, kStepModes); }
const char* ToString(FaultAction action) { return EnumToString(action, kFaultActions); }

double InitialAngle(const Config& config, AgentId id) {
  if (id < 1 || id > config.agents.count) {
    throw std::out_of_range("InitialAngle: agent id " + std::to_string(id) + " not in 1.." +
                            std::to_string(config.agents.count));
  }
  const auto index = static_cast<std::size_t>(id - 1);
  if (!config.agents.initial_angles_rad.empty()) return config.agents.initial_angles_rad[index];
  return kTwoPi / static_cast<double>(config.agents.count) * static_cast<double>(id - 1);
}

StateVector InitialState(const Config& config) {
  StateVector x0 = StateVector::Zero(config.filter.motion_model.StateDim());
  x0.head<2>() = config.filter.initial_estimate_m;  // velocity (if any) starts at 0
  return x0;
}

StateMatrix InitialCovariance(const Config& config) {
  const int n = config.filter.motion_model.StateDim();
  StateMatrix P0 = StateMatrix::Zero(n, n);
  P0.topLeftCorner<2, 2>() = config.filter.initial_position_variance_m2 * Matrix2::Identity();
  if (n == 4) {
    P0.bottomRightCorner<2, 2>() =
        config.filter.initial_velocity_variance_m2ps2 * Matrix2::Identity();
  }
  return P0;
}

}  // namespace deif
