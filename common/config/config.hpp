// Scenario configuration: plain structs, parsed from YAML by one function per section.
// Every key, its unit and its default are documented in configs/default.yaml.
#pragma once

#include <stdexcept>
#include <string>
#include <vector>

#include "common/core/control_law.hpp"
#include "common/core/models.hpp"
#include "common/core/types.hpp"


namespace deif {

// A configuration error: names the file, the key (dotted path) and the line where known.
class ConfigError : public std::runtime_error {
 public:
  ConfigError(std::string file, std::string key, int line, const std::string& reason);
  const std::string& file() const { return file_; }
  const std::string& key() const { return key_; }
  int line() const { return line_; }  // 1-based; 0 when unknown

 private:
  std::string file_;
  std::string key_;
  int line_;
};

enum class StepMode { kLockStep, kRealTime };

struct ScenarioConfig {
  std::string name = "default";
  std::uint64_t seed = 1;
  StepIndex steps = 300;        // number of measurement steps (k = 1..steps)
  double dt_s = 0.1;            // model time step
  StepMode mode = StepMode::kLockStep;
  double period_s = 0.05;       // real-time mode: wall-clock period of a step
};

struct TargetConfig {
  TrajectoryConfig trajectory;
  double range_noise_variance_m2 = 5.3e-4;  // the TRUE noise of the published ranges
};

struct FilterConfig {
  MotionModel motion_model;           // kind, dt (= scenario.dt_s) and process noise
  double range_variance_m2 = 5.3e-4;  // R_j used by every filter
  Vector2 initial_estimate_m = Vector2::Zero();
  double initial_position_variance_m2 = 1.0;  // P0 position block = v I2
  double initial_velocity_variance_m2ps2 = 1.0;  // P0 velocity block (constant velocity)
};

struct AgentsConfig {
  int count = 4;
  std::vector<double> initial_angles_rad;  // length == count; empty means evenly spaced
  Vector2 initial_centre_m = Vector2::Zero();  // the circle the agents start on
  double radius_m = 2.0;
  double max_speed_mps = 1.0;
  ControlLawKind control_law = ControlLawKind::kVoronoi;
};

struct NetworkConfig {
  int domain_id = 0;
  double liveliness_lease_s = 0.4;   // agent writers' MANUAL_BY_TOPIC lease [s]
  double participant_lease_s = 1.0;  // participant lease duration
  double participant_announcement_s = 0.25;
  double step_timeout_s = 2.0;       // wait for contributions / states before moving on
  double start_timeout_s = 30.0;     // wait for the expected agents before step 1
  int fusion_window_steps = 2;       // contributions older/newer than this are dropped
};

enum class FaultAction { kKill, kStop, kCont, kRestartTarget };

struct FaultConfig {
  StepIndex step = 0;
  FaultAction action = FaultAction::kKill;
  AgentId agent_id = -1;  // not used by kRestartTarget
};

struct Config {
  std::string source;  // the file it was read from (or a label for inline YAML)
  ScenarioConfig scenario;
  TargetConfig target;
  FilterConfig filter;
  SensingFunction sensing;
  AgentsConfig agents;
  NetworkConfig network;
  std::vector<FaultConfig> faults;
};

// Parse a YAML document. source_name is what error messages call the file.
// Throws ConfigError on any unknown key, wrong type, out-of-range value or inconsistency.
Config ParseConfig(const std::string& yaml_text, const std::string& source_name);
// Read and parse a file. A missing or unreadable file is a ConfigError too.
Config LoadConfig(const std::string& path);

// The configuration written back as YAML (for summary.json and reproducibility).
std::string ToYaml(const Config& config);

const char* ToString(ControlLawKind law);
const char* ToString(MotionModelKind kind);
const char* ToString(TrajectoryKind kind);
const char* ToString(StepMode mode);
const char* ToString(FaultAction action);

// The initial angle of agent id (1-based ids 1..count) per the config.
double InitialAngle(const Config& config, AgentId id);
// The filter's initial state and covariance for the configured motion model.
StateVector InitialState(const Config& config);
StateMatrix InitialCovariance(const Config& config);

}  // namespace deif
