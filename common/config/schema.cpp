// The schema table: every configuration key, declared once. See schema.hpp.
//
// Each key names its Config field with an accessor lambda; its type follows from the
// field's C++ type. Ranges are inclusive unless written Above / Below. The rules that
// involve two keys (participant_announcement_s < participant_lease_s, a fault's agent
// within agents.count, ...) are code, after the table is applied (config.cpp).
#include "common/config/schema.hpp"

#include <yaml-cpp/yaml.h>

#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <limits>
#include <map>
#include <type_traits>
#include <utility>

#include "common/config/config.hpp"
#include "common/config/schema_access.hpp"

namespace deif {

namespace {

// Limits a user can see. A day bounds every duration: longer is a typo, and 1e10 s would
// overflow a conversion to nanoseconds.
constexpr double kMaxSeconds = 86400.0;
constexpr double kMaxCoordinate = 1e6;  // |coordinate|, radius, speed, rate [SI units]
constexpr double kMaxVariance = 1e6;
constexpr double kMaxSteps = 10'000'000;
constexpr double kMaxAgents = 512;
constexpr double kMaxStepWindow = 1000;  // fusion_window_steps, history_steps

// ---------------------------------------------------------------------------------------
// C++ field <-> SchemaValue.

template <typename T>
constexpr KeyType TypeOf() {
  if constexpr (std::is_same_v<T, double>) return KeyType::kDouble;
  if constexpr (std::is_same_v<T, int>) return KeyType::kInt;
  if constexpr (std::is_same_v<T, std::int64_t>) return KeyType::kInt64;
  if constexpr (std::is_same_v<T, std::uint64_t>) return KeyType::kUint64;
  if constexpr (std::is_same_v<T, bool>) return KeyType::kBool;
  if constexpr (std::is_same_v<T, std::string>) return KeyType::kString;
  if constexpr (std::is_enum_v<T>) return KeyType::kEnum;
  if constexpr (std::is_same_v<T, Vector2>) return KeyType::kVector2;
  if constexpr (std::is_same_v<T, std::vector<double>>) return KeyType::kDoubleList;
  if constexpr (std::is_same_v<T, std::vector<int>>) return KeyType::kIntList;
  return KeyType::kRecordList;
}

template <typename T>
SchemaValue ToValue(const T& value) {
  if constexpr (std::is_enum_v<T>) {
    return std::string(ToString(value));
  } else if constexpr (std::is_same_v<T, int>) {
    return std::int64_t{value};
  } else if constexpr (std::is_same_v<T, std::vector<int>>) {
    return std::vector<std::int64_t>(value.begin(), value.end());
  } else {
    return value;
  }
}

template <typename T>
void FromValue(const SchemaValue& value, T* out) {
  if constexpr (std::is_enum_v<T>) {
    FromString(std::get<std::string>(value), out);
  } else if constexpr (std::is_same_v<T, int>) {
    *out = static_cast<int>(std::get<std::int64_t>(value));  // the range fits an int
  } else if constexpr (std::is_same_v<T, std::vector<int>>) {
    const auto& values = std::get<std::vector<std::int64_t>>(value);
    out->clear();
    for (const std::int64_t v : values) out->push_back(static_cast<int>(v));
  } else {
    *out = std::get<T>(value);
  }
}

// ---------------------------------------------------------------------------------------
// The builders the table is written with.

template <typename T>
class KeyBuilder {
 public:
  KeyBuilder(KeySpec* spec, KeyAccess* access) : spec_(spec), access_(access) {}

  KeyBuilder& Default(const T& value) {
    access_->default_value = ToValue(value);
    return *this;
  }
  KeyBuilder& AtLeast(double value) { return Min(value, true); }
  KeyBuilder& Above(double value) { return Min(value, false); }
  KeyBuilder& AtMost(double value) { return Max(value, true); }
  KeyBuilder& Below(double value) { return Max(value, false); }
  KeyBuilder& Within(double limit) { return AtLeast(-limit).AtMost(limit); }  // |x| <= limit
  // A duration: > 0 and at most a day.
  KeyBuilder& Seconds() { return Above(0.0).AtMost(kMaxSeconds).Unit("s"); }
  KeyBuilder& Variance(const std::string& unit) {
    return Above(0.0).AtMost(kMaxVariance).Unit(unit);
  }
  KeyBuilder& Probability() { return AtLeast(0.0).AtMost(1.0); }
  KeyBuilder& OrInfinity() {
    spec_->allow_infinity = true;
    return *this;
  }
  KeyBuilder& Length(std::size_t min, std::size_t max) {
    spec_->min_length = min;
    spec_->max_length = max;
    return *this;
  }
  KeyBuilder& Unit(const std::string& unit) {
    spec_->unit = unit;
    return *this;
  }
  KeyBuilder& Note(const std::string& note) {
    spec_->range_note = note;
    return *this;
  }
  KeyBuilder& Expected(const std::string& what) {
    spec_->expected = what;
    return *this;
  }
  // rule(value) -> the reason the value is refused, or "".
  template <typename Rule>
  KeyBuilder& Check(Rule rule) {
    access_->check = [rule](const SchemaValue& value) {
      T v{};
      FromValue(value, &v);
      return std::string(rule(v));
    };
    return *this;
  }
  KeyBuilder& Required() {
    spec_->required = true;
    return *this;
  }
  KeyBuilder& Doc(const std::string& description) {
    spec_->description = description;
    return *this;
  }

 private:
  KeyBuilder& Min(double value, bool inclusive) {
    spec_->min = Bound{value, inclusive};
    return *this;
  }
  KeyBuilder& Max(double value, bool inclusive) {
    spec_->max = Bound{value, inclusive};
    return *this;
  }

  KeySpec* spec_;
  KeyAccess* access_;
};

// The keys of one section (Record = Config) or of one record list's elements.
template <typename Record>
class Table {
 public:
  Table(std::vector<KeySpec>* keys, std::string section, std::string prefix)
      : keys_(keys), section_(std::move(section)), prefix_(std::move(prefix)) {}

  // A key stored as is in the field `ref(record)` returns.
  template <typename Ref>
  auto Add(const std::string& name, Ref ref) {
    using T = std::remove_cv_t<std::remove_reference_t<decltype(ref(std::declval<Record&>()))>>;
    KeyAccess* access = nullptr;
    KeySpec* spec = NewKey(name, TypeOf<T>(), &access);
    if constexpr (std::is_enum_v<T>) spec->enum_names = EnumNames<T>();
    access->get = [ref](const void* record) -> std::optional<SchemaValue> {
      return ToValue(ref(*static_cast<Record*>(const_cast<void*>(record))));
    };
    access->set = [ref](void* record, const SchemaValue& value) {
      FromValue(value, &ref(*static_cast<Record*>(record)));
    };
    return KeyBuilder<T>(spec, access);
  }

  // A key of YAML type T stored some other way: get(record) -> std::optional<T> (nullopt:
  // the record does not have the key), set(record, T).
  template <typename T, typename Get, typename Set>
  KeyBuilder<T> Custom(const std::string& name, Get get, Set set) {
    KeyAccess* access = nullptr;
    KeySpec* spec = NewKey(name, TypeOf<T>(), &access);
    access->get = [get](const void* record) -> std::optional<SchemaValue> {
      const std::optional<T> value = get(*static_cast<const Record*>(record));
      if (!value) return std::nullopt;
      return ToValue(*value);
    };
    access->set = [set](void* record, const SchemaValue& value) {
      T v{};
      FromValue(value, &v);
      set(*static_cast<Record*>(record), v);
    };
    return KeyBuilder<T>(spec, access);
  }

  // A list of records (mappings), the vector `ref(record)` returns; add_fields(table)
  // declares the keys of one element.
  template <typename Ref, typename AddFields>
  KeyBuilder<int> Records(const std::string& name, const std::string& noun, Ref ref,
                          AddFields add_fields) {
    using Vector = std::remove_reference_t<decltype(ref(std::declval<Record&>()))>;
    using Element = typename Vector::value_type;
    KeyAccess* access = nullptr;
    KeySpec* spec = NewKey(name, KeyType::kRecordList, &access);
    spec->element_noun = noun;
    spec->default_yaml = "[]";
    Table<Element> fields(&spec->fields, spec->key + "[]", spec->key + "[]");
    add_fields(fields);
    access->size = [ref](const void* record) {
      return ref(*static_cast<Record*>(const_cast<void*>(record))).size();
    };
    access->element = [ref](const void* record, std::size_t i) -> const void* {
      return &ref(*static_cast<Record*>(const_cast<void*>(record)))[i];
    };
    access->append = [ref](void* record) -> void* {
      Vector& v = ref(*static_cast<Record*>(record));
      v.emplace_back();
      return &v.back();
    };
    access->clear = [ref](void* record) { ref(*static_cast<Record*>(record)).clear(); };
    return KeyBuilder<int>(spec, access);
  }

 private:
  KeySpec* NewKey(const std::string& name, KeyType type, KeyAccess** access) {
    KeySpec spec;
    spec.section = section_;
    spec.name = name;
    spec.key = prefix_.empty() ? name : prefix_ + "." + name;
    spec.type = type;
    auto shared = std::make_shared<KeyAccess>();
    *access = shared.get();
    spec.access = std::move(shared);
    keys_->push_back(std::move(spec));
    return &keys_->back();
  }

  std::vector<KeySpec>* keys_;
  std::string section_;
  std::string prefix_;
};

// ---------------------------------------------------------------------------------------
// The table.

// network.discovery_server: "host:port" or "[v6 address]:port", port 1..65535.
std::string CheckHostPort(const std::string& text) {
  const std::string rule = "must be host:port with a port in 1..65535";
  const std::size_t colon = text.rfind(':');
  if (colon == std::string::npos || colon == 0) return rule;
  const std::string host = text.substr(0, colon);
  const std::string port = text.substr(colon + 1);
  if (port.empty() || port.size() > 5 || port[0] == '0' ||
      port.find_first_not_of("0123456789") != std::string::npos || std::stoi(port) > 65535) {
    return rule;
  }
  const bool bracketed = host.size() > 2 && host.front() == '[' && host.back() == ']';
  const std::string name = bracketed ? host.substr(1, host.size() - 2) : host;
  const char* allowed =
      bracketed ? "0123456789abcdefABCDEF:."
                : "abcdefghijklmnopqrstuvwxyzABCDEFGHIJKLMNOPQRSTUVWXYZ0123456789.-_";
  if (name.empty() || name.find_first_not_of(allowed) != std::string::npos) {
    return rule;
  }
  return "";
}

void AddScenario(std::vector<KeySpec>* keys) {
  Table<Config> t(keys, "scenario", "scenario");
  t.Add("name", [](Config& c) -> auto& { return c.scenario.name; })
      .Default("default")
      .Length(1, 128)
      .Note("printable UTF-8")
      .Doc("Label of the run in logs and summary.json.");
  t.Add("seed", [](Config& c) -> auto& { return c.scenario.seed; })
      .Default(1)
      .Doc("Seed of every random draw (range noise, the target's random walk, the simulated "
           "network). The same seed gives bit-identical runs.");
  t.Add("steps", [](Config& c) -> auto& { return c.scenario.steps; })
      .Default(300)
      .AtLeast(1)
      .AtMost(kMaxSteps)
      .Unit("steps")
      .Doc("Number of measurement steps k = 1..steps.");
  t.Add("dt_s", [](Config& c) -> auto& { return c.scenario.dt_s; })
      .Default(0.1)
      .Seconds()
      .Doc("Model time step: the trajectory is evaluated at t = k dt_s, and it is the "
           "filter's dt.");
  t.Add("mode", [](Config& c) -> auto& { return c.scenario.mode; })
      .Default(StepMode::kLockStep)
      .Doc("lockstep: the target advances once every agent finished the step (tests, "
           "experiments); realtime: one step per period_s of wall-clock time (virtual time "
           "in the in-process simulation).");
  t.Add("period_s", [](Config& c) -> auto& { return c.scenario.period_s; })
      .Default(0.05)
      .Seconds()
      .Doc("realtime mode: the period of one step.");
}

void AddTarget(std::vector<KeySpec>* keys) {
  Table<Config> t(keys, "target", "target");
  t.Add("trajectory", [](Config& c) -> auto& { return c.target.trajectory.kind; })
      .Default(TrajectoryKind::kFigureEight)
      .Doc("The true path: figure_eight [sin t, sin t cos t] (eq 5.3), figure_eight_shifted "
           "[sin t, sin t cos t - 1] (eq 5.7), circle (start_m + circle_radius_m [cos wt, "
           "sin wt]), line (start_m + velocity_mps t), static (start_m), random_walk "
           "(start_m plus a walk of process_noise_variance_m2 per step).");
  t.Add("start_m", [](Config& c) -> auto& { return c.target.trajectory.start_m; })
      .Default(Vector2(0.0, 0.0))
      .Within(kMaxCoordinate)
      .Unit("m")
      .Doc("[x, y] start of the line, static and random_walk paths; centre of the circle.");
  t.Add("velocity_mps", [](Config& c) -> auto& { return c.target.trajectory.velocity_mps; })
      .Default(Vector2(0.1, 0.0))
      .Within(kMaxCoordinate)
      .Unit("m/s")
      .Doc("[vx, vy] of the line path.");
  t.Add("circle_radius_m", [](Config& c) -> auto& { return c.target.trajectory.circle_radius_m; })
      .Default(1.0)
      .Above(0.0)
      .AtMost(kMaxCoordinate)
      .Unit("m")
      .Doc("Radius of the circle path.");
  t.Add("angular_rate_radps",
        [](Config& c) -> auto& { return c.target.trajectory.angular_rate_radps; })
      .Default(0.5)
      .Within(kMaxCoordinate)
      .Unit("rad/s")
      .Doc("Angular rate w of the circle path (negative: clockwise).");
  t.Add("process_noise_variance_m2",
        [](Config& c) -> auto& { return c.target.trajectory.process_noise_variance; })
      .Default(0.0)
      .AtLeast(0.0)
      .AtMost(kMaxVariance)
      .Unit("m^2")
      .Doc("Variance of a random-walk perturbation added to the truth every step. It is the "
           "motion itself for random_walk (set it > 0 there); 0 keeps the other paths "
           "smooth.");
  t.Add("range_noise_variance_m2",
        [](Config& c) -> auto& { return c.target.range_noise_variance_m2; })
      .Default(5.3e-4)
      .Variance("m^2")
      .Doc("The TRUE variance of the noise on every published range (the thesis's "
           "0.00053). What the filters assume is filter.range_variance_m2.");
}

void AddFilter(std::vector<KeySpec>* keys) {
  Table<Config> t(keys, "filter", "filter");
  t.Add("motion_model", [](Config& c) -> auto& { return c.filter.motion_model.kind; })
      .Default(MotionModelKind::kRandomWalk)
      .Doc("The filter's target model: random_walk (eq 5.1, state [x, y]) or "
           "constant_velocity (state [x, y, vx, vy]).");
  t.Add("process_noise", [](Config& c) -> auto& { return c.filter.motion_model.process_noise; })
      .Default(1.3e-4)
      .Variance("m^2 or m^2/s^3")
      .Doc("q. random_walk: the per-step position variance [m^2], Q = q I2 (the thesis's "
           "0.00013). constant_velocity: the white-acceleration spectral density [m^2/s^3].");
  t.Add("range_variance_m2", [](Config& c) -> auto& { return c.filter.range_variance_m2; })
      .Default(5.3e-4)
      .Variance("m^2")
      .Doc("R, the range variance every filter assumes.");
  t.Add("initial_estimate_m", [](Config& c) -> auto& { return c.filter.initial_estimate_m; })
      .Default(Vector2(0.0, 0.0))
      .Within(kMaxCoordinate)
      .Unit("m")
      .Doc("Initial position estimate [x, y]; the initial velocity estimate is 0.");
  t.Add("initial_position_variance_m2",
        [](Config& c) -> auto& { return c.filter.initial_position_variance_m2; })
      .Default(1.0)
      .Variance("m^2")
      .Doc("P0 position block = v I2.");
  t.Add("initial_velocity_variance_m2ps2",
        [](Config& c) -> auto& { return c.filter.initial_velocity_variance_m2ps2; })
      .Default(1.0)
      .Variance("m^2/s^2")
      .Doc("P0 velocity block = v I2 (constant_velocity only).");
  t.Add("innovation_gate_sigma", [](Config& c) -> auto& { return c.filter.innovation_gate_sigma; })
      .Default(20.0)
      .AtLeast(0.0)
      .AtMost(kMaxVariance)
      .Unit("sigma")
      .Doc("Innovation gate: an agent whose own range is further from its predicted range "
           "than this many standard deviations, sqrt(H P H^T + R) with the predicted P, sends "
           "an empty contribution for that step (the range carries no information), up to 5 "
           "steps in a row; from the 6th its ranges are fused until one passes (the estimate "
           "is then what is wrong; docs/PROTOCOL.md); 0: no gate.");
}

void AddSensing(std::vector<KeySpec>* keys) {
  Table<Config> t(keys, "sensing", "sensing");
  t.Add("c0", [](Config& c) -> auto& { return c.sensing.c0; })
      .Default(0.0)
      .Within(kMaxCoordinate)
      .Unit("m^beta")
      .Doc("f below r0_m.");
  t.Add("r0_m", [](Config& c) -> auto& { return c.sensing.r0_m; })
      .Default(0.0)
      .AtLeast(0.0)
      .AtMost(kMaxCoordinate)
      .Unit("m")
      .Doc("Inner radius R0.");
  t.Add("r1_m", [](Config& c) -> auto& { return c.sensing.r1_m; })
      .Default(std::numeric_limits<double>::infinity())
      .Above(0.0)
      .AtMost(kMaxCoordinate)
      .OrInfinity()
      .Note("> r0_m")
      .Unit("m")
      .Doc("Outer radius R1: f is constant beyond it, so a finite R1 limits the sensing "
           "range; .inf = unlimited.");
  t.Custom<int>(
       "beta",
       [](const Config& c) -> std::optional<int> { return static_cast<int>(c.sensing.beta); },
       [](Config& c, int beta) { c.sensing.beta = beta; })
      .Default(1)
      .AtLeast(-1)
      .AtMost(64)
      .Note("not 0")
      .Expected("a positive integer or -1")
      .Check([](int beta) { return beta == 0 ? "must be a positive integer or -1" : ""; })
      .Doc("Exponent of f: a positive integer or -1.");
}

void AddAgents(std::vector<KeySpec>* keys) {
  Table<Config> t(keys, "agents", "agents");
  t.Add("count", [](Config& c) -> auto& { return c.agents.count; })
      .Default(4)
      .AtLeast(2)
      .AtMost(kMaxAgents)
      .Doc("Number of agents N (ids 1..N).");
  t.Add("initial_angles_rad", [](Config& c) -> auto& { return c.agents.initial_angles_rad; })
      .Default({})
      .Within(kMaxCoordinate)
      .Note("exactly agents.count entries, or []")
      .Unit("rad")
      .Doc("Starting angle of agents 1..N about initial_centre_m, counter-clockwise from +x. "
           "[]: evenly spaced, 2 pi / N (id - 1). Changing agents.count with --set without "
           "giving angles drops a list of another length.");
  t.Add("initial_centre_m", [](Config& c) -> auto& { return c.agents.initial_centre_m; })
      .Default(Vector2(0.0, 0.0))
      .Within(kMaxCoordinate)
      .Unit("m")
      .Doc("Centre [x, y] of the circle the agents start on.");
  t.Add("radius_m", [](Config& c) -> auto& { return c.agents.radius_m; })
      .Default(2.0)
      .Above(0.0)
      .AtMost(kMaxCoordinate)
      .Unit("m")
      .Doc("Radius of the circle the agents start on and keep about the estimate.");
  t.Add("max_speed_mps", [](Config& c) -> auto& { return c.agents.max_speed_mps; })
      .Default(1.0)
      .AtLeast(0.0)
      .AtMost(kMaxCoordinate)
      .Unit("m/s")
      .Doc("Speed limit; 0 never moves.");
  t.Add("control_law", [](Config& c) -> auto& { return c.agents.control_law; })
      .Default(ControlLawKind::kVoronoi)
      .Doc("midpoint (law 1, eq 3.2), voronoi (law 2, eq 3.6) or stationary (no motion); with "
           "either law a lone agent stands still (docs/ARCHITECTURE.md).");
}

void AddNetwork(std::vector<KeySpec>* keys) {
  Table<Config> t(keys, "network", "network");
  t.Add("domain_id", [](Config& c) -> auto& { return c.network.domain_id; })
      .Default(0)
      .AtLeast(0)
      .AtMost(232)
      .Doc("DDS domain. Fast DDS exits for domain ids above 232.");
  t.Add("liveliness_lease_s", [](Config& c) -> auto& { return c.network.liveliness_lease_s; })
      .Default(0.4)
      .Seconds()
      .Doc("MANUAL_BY_TOPIC liveliness lease of the agents' contribution and state writers. A "
           "killed agent is excluded about one lease after its last write (measured 0.40 s "
           "with 0.4, 0.50 s with 0.5). Shorter is quicker but risks excluding an agent that "
           "is only starved of CPU (see configs/large.yaml). From 28 agents on, the processes "
           "use a longer lease, so that two renewals per lease of every writer to every reader "
           "stay within a budget: 2.08 s at 64 agents (docs/BENCHMARKS.md, \"Liveliness at "
           "large N\").");
  t.Add("liveliness_grace_s", [](Config& c) -> auto& { return c.network.liveliness_grace_s; })
      .Default(0.2)
      .AtLeast(0.0)
      .AtMost(kMaxSeconds)
      .Unit("s")
      .Doc("A lapse of a writer's liveliness counts as a loss only if the writer stays silent "
           "this much longer: a process starved of CPU, or a burst of lost packets, makes a "
           "live peer lapse for a moment, and excluding it would change what is fused. A "
           "killed agent is excluded about liveliness_lease_s + liveliness_grace_s after "
           "its last write. 0: every lapse is a loss. In the tree exchange from 28 agents "
           "on, where a peer's writer renews its liveliness only twice a lease, an agent "
           "holds a peer's lapse until 4 renewals in a row went missing if that is longer: "
           "0.92 s at 32 agents, 3.64 s at 64. Each loss that is undone soon after (the "
           "writer back: the network lost its renewals) doubles the grace a process gives "
           "from then on, up to 8 x and participant_lease_s; a minute without one halves it "
           "(docs/PROTOCOL.md, \"Slow is not gone\").");
  t.Add("liveliness_assertions_per_lease",
        [](Config& c) -> auto& { return c.network.liveliness_assertions_per_lease; })
      .Default(8)
      .AtLeast(1)
      .AtMost(100)
      .Doc("How many liveliness renewals an idle writer sends per lease. More survive packet "
           "loss: at 20 % loss, 8 per lease leave a 0.2^8 = 3e-6 chance of a false exclusion "
           "per lease. From 14 agents on the processes send fewer, within a budget of 4000 "
           "renewal messages a second over the network, but never fewer than 2 per lease "
           "(unless 1 is set here): 5 at 16 agents, 2 at 64 (docs/BENCHMARKS.md, \"Liveliness "
           "at large N\").");
  t.Add("participant_lease_s", [](Config& c) -> auto& { return c.network.participant_lease_s; })
      .Default(5.0)
      .Seconds()
      .Doc("Participant lease: a participant silent this long is dropped with all its "
           "readers and writers. Long on purpose: a partition shorter than the lease does not "
           "tear down matching, and a long lease avoids a Fast DDS assertion under CPU "
           "starvation. Where the announcement period grows (participant_announcement_s), "
           "the lease grows with it: as many periods long as configured (20.8 s at 64 "
           "agents with the defaults).");
  t.Add("participant_announcement_s",
        [](Config& c) -> auto& { return c.network.participant_announcement_s; })
      .Default(0.5)
      .Seconds()
      .Note("< participant_lease_s")
      .Doc("Period of the participant announcements that keep the participant lease alive. "
           "From 32 agents on, the processes announce less often, so that the whole network "
           "receives at most 2000 announcements a second: every 2.08 s at 64 agents (a "
           "64-agent lock-step ran 1.3 x as fast; docs/BENCHMARKS.md, \"Participant "
           "announcements at large N\").");
  t.Add("step_timeout_s", [](Config& c) -> auto& { return c.network.step_timeout_s; })
      .Default(2.0)
      .Seconds()
      .Doc("lockstep: the longest wait for contributions and states before moving on.");
  t.Add("start_timeout_s", [](Config& c) -> auto& { return c.network.start_timeout_s; })
      .Default(30.0)
      .Seconds()
      .Doc("The longest wait for the target: at the start, and when it falls silent "
           "mid-run. The target's wait for the agents at the start: it starts with whoever "
           "is there once this long has passed without a new agent.");
  t.Add("fusion_window_steps", [](Config& c) -> auto& { return c.network.fusion_window_steps; })
      .Default(2)
      .AtLeast(0)
      .AtMost(kMaxStepWindow)
      .Unit("steps")
      .Doc("Contributions up to this many steps ahead of an agent's step are held until it "
           "gets there; further ahead they are dropped (late ones: history_steps).");
  t.Add("history_steps", [](Config& c) -> auto& { return c.network.history_steps; })
      .Default(50)
      .AtLeast(1)
      .AtMost(kMaxStepWindow)
      .Unit("steps")
      .Doc("Steps an agent keeps for late fusion: a contribution up to this many steps late "
           "is still fused into its step and the estimate re-propagated. Also the DDS "
           "history depth, so a partition shorter than this heals exactly.");
  t.Add("heartbeat_period_s", [](Config& c) -> auto& { return c.network.heartbeat_period_s; })
      .Default(0.005)
      .AtLeast(0.001)
      .AtMost(10.0)
      .Unit("s")
      .Doc("Heartbeat period of the reliable writers: a lost sample is repaired about one "
           "period later. Fast DDS's default of 3 s is far longer than a step. Heartbeats "
           "are sent only while samples are unacknowledged. 5 ms repairs a loss well within "
           "a 10 Hz step at 20 % loss (docs/PROTOCOL.md, measured with deif_sim). From 10 "
           "agents on, the processes use a longer period, so that the network's "
           "heartbeats stay within a budget (docs/BENCHMARKS.md, \"Heartbeats at large N\"); "
           "in real time the writers with a few readers each keep a shorter one: the "
           "relays', and over UDPv4 the states' and each agent's ranges' "
           "(docs/BENCHMARKS.md, \"Repairs in real time\").");
  t.Add("nack_response_delay_s",
        [](Config& c) -> auto& { return c.network.nack_response_delay_s; })
      .Default(0.001)
      .AtLeast(0.0)
      .AtMost(10.0)
      .Unit("s")
      .Doc("How long a reliable writer waits before it answers a negative acknowledgement "
           "(a repair request) with the missing samples.");
  t.Add("heartbeat_response_delay_s",
        [](Config& c) -> auto& { return c.network.heartbeat_response_delay_s; })
      .Default(0.001)
      .AtLeast(0.0)
      .AtMost(10.0)
      .Unit("s")
      .Doc("How long a reliable reader waits before it answers a heartbeat with an "
           "acknowledgement or a repair request.");
  t.Add("deadline_fraction", [](Config& c) -> auto& { return c.network.deadline_fraction; })
      .Default(0.8)
      .Above(0.0)
      .AtMost(1.0)
      .Doc("realtime mode: an agent fuses what arrived within this fraction of the period "
           "after its range; later contributions are fused late (history_steps).");
  t.Add("exchange", [](Config& c) -> auto& { return c.network.exchange; })
      .Default(ExchangeKind::kAuto)
      .Note("tree needs security.enabled: false and ros2_naming: false")
      .Doc("How a step's contributions reach every agent. all_to_all: each agent writes its "
           "own on deif/contribution to every other, N (N - 1) deliveries a step. tree: the "
           "members form a tree of tree_fanout children per relay (by ascending id); each "
           "agent sends its subtree's contributions up as one batch on deif/relay_up and the "
           "root's batch of all of them comes back down on deif/relay_down, 2 (N - 1) "
           "deliveries a step, the same estimates bit for bit; relays are trusted to forward "
           "unchanged (docs/SCALING.md). auto: the tree from 17 agents on, unless "
           "security.enabled, ros2_naming or discovery: server; all_to_all otherwise.");
  t.Add("tree_fanout", [](Config& c) -> auto& { return c.network.tree_fanout; })
      .Default(0)
      .AtLeast(0)
      .AtMost(64)
      .Doc("exchange: tree: children per relay. Fewer: more hops in a row (about "
           "2 log_fanout N); more: more deliveries wait on one relay. 0: auto, the smallest "
           "fan-out (at least 4) whose tree holds every agent within two levels below the "
           "root: 4 up to 21 agents, 8 at 64, 11 at 128 (docs/SCALING.md).");
  t.Add("relay_wait_s", [](Config& c) -> auto& { return c.network.relay_wait_s; })
      .Default(0.02)
      .AtLeast(0.0)
      .AtMost(10.0)
      .Unit("s")
      .Doc("exchange: tree, realtime mode: how long a relay waits for its children's batches "
           "of a step, per level of the tree below it, before it forwards what it holds; at "
           "most deadline_fraction x period_s / (levels + 1), so that the root's wait leaves "
           "a share for the way down. A parent outwaits its children by one share. What "
           "comes later goes on at once and is fused late (docs/SCALING.md). In lockstep a "
           "relay waits at least a quarter of step_timeout_s, and gathers what comes later "
           "for half that wait.");
  t.Add("relay_lease_s", [](Config& c) -> auto& { return c.network.relay_lease_s; })
      .Default(0.0)
      .AtLeast(0.0)
      .AtMost(kMaxSeconds)
      .Unit("s")
      .Doc("exchange: tree: MANUAL_BY_TOPIC liveliness lease of a relay's writer to its "
           "children. A child whose parent stays silent this long plus liveliness_grace_s "
           "takes it for lost and moves under the next member up at once, before the "
           "members agree it is gone (which takes the longer lease of every agent's "
           "writers at large N: 2.08 s at 64 agents). A relay writer has at most "
           "tree_fanout readers, so this lease need not grow with N. An idle relay writer "
           "renews it up to 3 times a lease (at most liveliness_assertions_per_lease). 0: "
           "liveliness_lease_s (docs/SCALING.md, \"Losing a relay\").");
  t.Add("membership", [](Config& c) -> auto& { return c.network.membership; })
      .Default(MembershipKind::kAuto)
      .Note("roll_call needs the tree exchange")
      .Doc("How an agent knows which peers are members. all_pairs: by the liveliness of "
           "every peer's writer of deif/contribution, which every agent reads, N (N - 1) "
           "matched pairs renewed all the time. roll_call (exchange: tree only): by the "
           "target's roll call of each step; an agent reads no peer's deif/contribution, so "
           "no pair of agents is matched but along the tree. A peer the roll call leaves out "
           "is lost at once, one it names again is back; an agent cut off from the target "
           "keeps its members until it hears the target again (docs/PROTOCOL.md, "
           "\"Membership from the roll call\"). auto: roll_call over the tree from 28 agents "
           "on, where the budget of every pair's liveliness renewals already makes the "
           "agents' leases longer (a peer's own liveliness tells of a loss no sooner than the "
           "roll call); all_pairs otherwise.");
  t.Add("process_watch", [](Config& c) -> auto& { return c.network.process_watch; })
      .Default(true)
      .Doc("On one host, take an agent whose process ended (kill -9, a crash: the kernel "
           "released the locks of its shared-memory ports) for lost at once, instead of after "
           "its liveliness lease and grace; a frozen or starved process keeps its locks "
           "(docs/PROTOCOL.md, \"A process that ended\"). false: liveliness alone, as between "
           "hosts.");
  t.Add("transport", [](Config& c) -> auto& { return c.network.transport; })
      .Default(TransportKind::kShm)
      .Doc("shm: shared memory between processes on one host, plus UDPv4 for the others "
           "(the faster: docs/BENCHMARKS.md). udp: UDPv4 only, also between processes of "
           "one host; deif-run --hosts uses it, so that packet-loss rules apply.");
  t.Add("discovery", [](Config& c) -> auto& { return c.network.discovery; })
      .Default(DiscoveryKind::kSimple)
      .Doc("simple: multicast participant discovery (SPDP). server: the Fast DDS Discovery "
           "Server at discovery_server.");
  t.Add("discovery_server", [](Config& c) -> auto& { return c.network.discovery_server; })
      .Default("127.0.0.1:11811")
      .Length(1, 255)
      .Note("host:port, port 1..65535")
      .Check(CheckHostPort)
      .Doc("Address of the Discovery Server, used with discovery: server.");
  t.Add("ros2_naming", [](Config& c) -> auto& { return c.network.ros2_naming; })
      .Default(false)
      .Doc("Publish on rt/deif/... with ROS 2 type names, so that ROS 2 tools see the "
           "network.");
  t.Add("security.enabled", [](Config& c) -> auto& { return c.network.security.enabled; })
      .Default(false)
      .Note("needs ros2_naming: false and discovery: simple")
      .Doc("DDS Security (docs/SECURITY.md): every participant proves a certificate of the "
           "network's CA (PKI-DH), may publish only its own topics as its own id "
           "(Access-Permissions) and encrypts what it sends (AES-GCM-GMAC). A process without "
           "valid certificates sees nothing and is not heard.");
  t.Add("security.dir", [](Config& c) -> auto& { return c.network.security.dir; })
      .Default("")
      .Length(0, 4096)
      .Note("required with security.enabled")
      .Doc("Folder with ca.pem, governance.p7s and, per process, <name>.cert.pem, "
           "<name>.key.pem and <name>.permissions.p7s, where name is target, agent-<id> or "
           "observer-<m> (scripts/deif-certs writes them). Relative to the working directory. "
           "A bad or missing file stops the process at start (exit 2).");
}

void AddNetworkSim(std::vector<KeySpec>* keys) {
  Table<Config> t(keys, "network_sim", "network_sim");
  t.Add("loss", [](Config& c) -> auto& { return c.network_sim.loss; })
      .Default(0.0)
      .AtLeast(0.0)
      .Below(1.0)
      .Doc("Probability that one message is lost.");
  t.Add("delay_min_s", [](Config& c) -> auto& { return c.network_sim.delay_min_s; })
      .Default(0.0)
      .AtLeast(0.0)
      .AtMost(kMaxSeconds)
      .Unit("s")
      .Doc("Shortest one-way delay: every message is delayed uniformly in "
           "[delay_min_s, delay_max_s].");
  t.Add("delay_max_s", [](Config& c) -> auto& { return c.network_sim.delay_max_s; })
      .Default(0.0)
      .AtLeast(0.0)
      .AtMost(kMaxSeconds)
      .Note(">= delay_min_s")
      .Unit("s")
      .Doc("Longest one-way delay.");
  t.Add("duplicate", [](Config& c) -> auto& { return c.network_sim.duplicate; })
      .Default(0.0)
      .Probability()
      .Doc("Probability that a message is delivered twice.");
  t.Add("reorder", [](Config& c) -> auto& { return c.network_sim.reorder; })
      .Default(0.0)
      .Probability()
      .Doc("Probability that a message is held back behind the next one on its link.");
  t.Records("partitions", "partition", [](Config& c) -> auto& { return c.network_sim.partitions; },
            [](Table<PartitionConfig>& p) {
              p.Add("from_step", [](PartitionConfig& e) -> auto& { return e.from_step; })
                  .Required()
                  .AtLeast(1)
                  .AtMost(kMaxSteps)
                  .Note("<= scenario.steps")
                  .Unit("steps")
                  .Doc("First step of the partition.");
              p.Add("to_step", [](PartitionConfig& e) -> auto& { return e.to_step; })
                  .Required()
                  .AtLeast(1)
                  .AtMost(kMaxSteps)
                  .Note("from_step..scenario.steps")
                  .Unit("steps")
                  .Doc("Last step of the partition.");
              p.Add("group", [](PartitionConfig& e) -> auto& { return e.group; })
                  .Default({})
                  .Note("distinct agent ids in 1..agents.count")
                  .Doc("The agents cut off from the others. May be empty only with "
                       "with_target: true (the target alone is cut off).");
              p.Add("with_target", [](PartitionConfig& e) -> auto& { return e.with_target; })
                  .Default(false)
                  .Doc("The target is on the group's side of the cut.");
            })
      .Doc("Partitions by step window: during steps from_step..to_step the agents of group "
           "(and the target, with with_target: true) are cut off from everyone else.");
}

void AddFaults(std::vector<KeySpec>* keys) {
  Table<Config> t(keys, "", "");
  t.Records("faults", "fault", [](Config& c) -> auto& { return c.faults; },
            [](Table<FaultConfig>& f) {
              f.Add("step", [](FaultConfig& e) -> auto& { return e.step; })
                  .Required()
                  .AtLeast(1)
                  .AtMost(kMaxSteps)
                  .Note("<= scenario.steps")
                  .Unit("steps")
                  .Doc("The step at whose start the fault happens.");
              f.Add("action", [](FaultConfig& e) -> auto& { return e.action; })
                  .Required()
                  .Doc("kill: the agent dies for good (kill -9). stop: the agent is frozen "
                       "(SIGSTOP): no range, no part in the step; in the in-process "
                       "simulation it predicts only. cont: a stopped agent resumes "
                       "(SIGCONT). restart_target: the target restarts, so there are no "
                       "ranges at that step and the agents only predict (they still steer).");
              f.Custom<int>(
                   "agent",
                   [](const FaultConfig& e) -> std::optional<int> {
                     if (e.action == FaultAction::kRestartTarget) return std::nullopt;
                     return e.agent_id;
                   },
                   [](FaultConfig& e, int id) { e.agent_id = id; })
                  .Note("1..agents.count; required by kill, stop and cont, refused by "
                        "restart_target")
                  .Doc("The agent id.");
            })
      .Doc("Scripted faults, applied at the start of their step, in step order (file order "
           "within a step). cont needs an earlier stop of the same agent, nothing happens to "
           "a killed agent, and at least one agent must survive.");
}

// Writes the default texts once the table is complete.
void FillDefaults(std::vector<KeySpec>* keys) {
  for (KeySpec& spec : *keys) {
    if (spec.type == KeyType::kRecordList) {
      FillDefaults(&spec.fields);
    } else if (spec.access->default_value) {
      spec.default_yaml = ValueYaml(spec, *spec.access->default_value);
    }
  }
}

std::vector<KeySpec> BuildSchema() {
  std::vector<KeySpec> keys;
  AddScenario(&keys);
  AddTarget(&keys);
  AddFilter(&keys);
  AddSensing(&keys);
  AddAgents(&keys);
  AddNetwork(&keys);
  AddNetworkSim(&keys);
  AddFaults(&keys);
  FillDefaults(&keys);
  return keys;
}

// One paragraph per section, for the reference documentation.
const std::map<std::string, std::string>& SectionDescriptions() {
  static const std::map<std::string, std::string> descriptions = {
      {"scenario", "The run: its name, seed, length, time step and stepping mode."},
      {"target", "The simulated target: its true path and the true noise of the ranges it "
                 "publishes."},
      {"filter", "The filter every agent runs (the DEIF of section 4.5): motion model, "
                 "process noise, the range variance it assumes, initial estimate and "
                 "covariance."},
      {"sensing", "The sensing function f of eq (2.1): f(r) = c0 for r <= r0_m, r^beta + c1 "
                  "between r0_m and r1_m (c1 = c0 - r0_m^beta), constant beyond r1_m. The "
                  "defaults give f(r) = r, the plain range of eq (5.5)."},
      {"agents", "The agents: how many, where they start, the circle they keep about the "
                 "estimate, their speed limit and control law (chapter 3). Angles are in "
                 "radians, counter-clockwise from +x."},
      {"network", "The network between the processes: the DDS settings of the multi-process "
                  "agents and target (domain, leases, reliability timing, transport, "
                  "discovery) and the agents' fusion timing."},
      {"network_sim", "The simulated network of the in-process simulation (deif_sim only): "
                      "per-message loss, delay, duplication and reordering, and partitions. "
                      "Deterministic from scenario.seed."},
  };
  return descriptions;
}

std::vector<SectionSpec> BuildSections(const std::vector<KeySpec>& keys) {
  std::vector<SectionSpec> sections;
  for (const KeySpec& spec : keys) {
    const std::string name = spec.section.empty() ? spec.name : spec.section;
    if (sections.empty() || sections.back().name != name || spec.section.empty()) {
      SectionSpec section;
      section.name = name;
      section.is_key = spec.section.empty();
      const auto it = SectionDescriptions().find(name);
      section.description = it != SectionDescriptions().end() ? it->second : spec.description;
      sections.push_back(std::move(section));
    }
    sections.back().keys.push_back(&spec);
  }
  return sections;
}

void EmitValue(YAML::Emitter& out, const KeySpec& spec, const SchemaValue& value) {
  switch (spec.type) {
    case KeyType::kDouble:
      out << FormatNumber(std::get<double>(value));
      break;
    case KeyType::kInt:
    case KeyType::kInt64:
      out << std::to_string(std::get<std::int64_t>(value));
      break;
    case KeyType::kUint64:
      out << std::to_string(std::get<std::uint64_t>(value));
      break;
    case KeyType::kBool:
      out << std::get<bool>(value);
      break;
    case KeyType::kString:
      out << YAML::DoubleQuoted << std::get<std::string>(value);
      break;
    case KeyType::kEnum:
      out << std::get<std::string>(value);
      break;
    case KeyType::kVector2: {
      const Vector2& v = std::get<Vector2>(value);
      out << YAML::Flow << YAML::BeginSeq << FormatNumber(v.x()) << FormatNumber(v.y())
          << YAML::EndSeq;
      break;
    }
    case KeyType::kDoubleList:
      out << YAML::Flow << YAML::BeginSeq;
      for (const double v : std::get<std::vector<double>>(value)) out << FormatNumber(v);
      out << YAML::EndSeq;
      break;
    case KeyType::kIntList:
      out << YAML::Flow << YAML::BeginSeq;
      for (const std::int64_t v : std::get<std::vector<std::int64_t>>(value)) {
        out << std::to_string(v);
      }
      out << YAML::EndSeq;
      break;
    case KeyType::kRecordList:
      break;  // not a SchemaValue: EmitKeyValue
  }
}

}  // namespace

// ---------------------------------------------------------------------------------------

std::string FormatNumber(double value) {
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

void EmitKeyValue(YAML::Emitter& out, const KeySpec& spec, const void* record, bool flow) {
  if (spec.type != KeyType::kRecordList) {
    const std::optional<SchemaValue> value = spec.access->get(record);
    if (value) {
      EmitValue(out, spec, *value);
    } else {
      out << YAML::Null;
    }
    return;
  }
  const std::size_t n = spec.access->size(record);
  if (n == 0 || flow) out << YAML::Flow;
  out << YAML::BeginSeq;
  for (std::size_t i = 0; i < n; ++i) {
    const void* element = spec.access->element(record, i);
    out << YAML::Flow << YAML::BeginMap;
    for (const KeySpec& field : spec.fields) {
      const std::optional<SchemaValue> value = field.access->get(element);
      if (!value) continue;
      out << YAML::Key << field.name << YAML::Value;
      EmitValue(out, field, *value);
    }
    out << YAML::EndMap;
  }
  out << YAML::EndSeq;
}

std::string KeyValueYaml(const KeySpec& spec, const void* record) {
  YAML::Emitter out;
  EmitKeyValue(out, spec, record, /*flow=*/true);
  return out.c_str();
}

std::string ValueYaml(const KeySpec& spec, const SchemaValue& value) {
  YAML::Emitter out;
  EmitValue(out, spec, value);
  return out.c_str();
}

std::string KeySpec::TypeText() const {
  switch (type) {
    case KeyType::kDouble:
      return "number";
    case KeyType::kInt:
    case KeyType::kInt64:
    case KeyType::kUint64:
      return "integer";
    case KeyType::kBool:
      return "boolean";
    case KeyType::kString:
      return "string";
    case KeyType::kEnum:
      return "enum";
    case KeyType::kVector2:
      return "[x, y]";
    case KeyType::kDoubleList:
      return "list of numbers";
    case KeyType::kIntList:
      return "list of integers";
    case KeyType::kRecordList: {
      std::string names;
      for (const KeySpec& field : fields) names += (names.empty() ? "" : ", ") + field.name;
      return "list of {" + names + "}";
    }
  }
  return "";
}

std::string KeySpec::RangeText() const {
  std::string text;
  const bool integral = type == KeyType::kInt || type == KeyType::kInt64 ||
                        type == KeyType::kIntList;
  if (type == KeyType::kUint64) {
    text = "0..2^64-1";
  } else if (type == KeyType::kString) {
    if (max_length > 0) {
      text = std::to_string(min_length) + ".." + std::to_string(max_length) + " characters";
    }
  } else if (type == KeyType::kEnum) {
    for (const std::string& option : enum_names) text += (text.empty() ? "" : ", ") + option;
  } else if (integral && min && max && min->inclusive && max->inclusive) {
    text = FormatNumber(min->value) + ".." + FormatNumber(max->value);
  } else {
    if (min) text = std::string(min->inclusive ? ">= " : "> ") + FormatNumber(min->value);
    if (max) {
      text += std::string(text.empty() ? "" : " and ") + (max->inclusive ? "<= " : "< ") +
              FormatNumber(max->value);
    }
    if (allow_infinity) text += ", or .inf";
  }
  if ((type == KeyType::kVector2 || type == KeyType::kDoubleList ||
       type == KeyType::kIntList) &&
      !text.empty()) {
    text = "each " + text;
  }
  if (!range_note.empty()) text += (text.empty() ? "" : "; ") + range_note;
  return text;
}

const std::vector<KeySpec>& Schema() {
  static const std::vector<KeySpec> schema = BuildSchema();
  return schema;
}

const std::vector<SectionSpec>& Sections() {
  static const std::vector<SectionSpec> sections = BuildSections(Schema());
  return sections;
}

const KeySpec* FindKey(std::string_view key) {
  for (const KeySpec& spec : Schema()) {
    if (spec.key == key) return &spec;
    for (const KeySpec& field : spec.fields) {
      if (field.key == key) return &field;
    }
  }
  return nullptr;
}

void VisitNested(const NamedKeys& keys,
                 const std::function<void(const std::string&, const KeySpec&)>& leaf,
                 const std::function<void(const std::string&, const NamedKeys&)>& group) {
  std::vector<std::string> done;
  for (const auto& [name, spec] : keys) {
    const std::size_t dot = name.find('.');
    if (dot == std::string::npos) {
      leaf(name, *spec);
      continue;
    }
    const std::string head = name.substr(0, dot);
    if (std::find(done.begin(), done.end(), head) != done.end()) continue;
    done.push_back(head);
    NamedKeys nested;
    for (const auto& [other, other_spec] : keys) {
      if (other.compare(0, head.size() + 1, head + ".") == 0) {
        nested.emplace_back(other.substr(head.size() + 1), other_spec);
      }
    }
    group(head, nested);
  }
}

std::vector<std::string> KeyPath(const KeySpec& spec) {
  std::vector<std::string> path;
  if (!spec.section.empty()) path.push_back(spec.section);
  for (std::size_t start = 0;;) {
    const std::size_t dot = spec.name.find('.', start);
    path.push_back(spec.name.substr(start, dot - start));
    if (dot == std::string::npos) break;
    start = dot + 1;
  }
  return path;
}

void VisitConfig(const Config& config,
                 const std::function<void(const KeySpec& spec, const std::string& yaml)>& visit) {
  for (const KeySpec& spec : Schema()) visit(spec, KeyValueYaml(spec, &config));
}

}  // namespace deif
