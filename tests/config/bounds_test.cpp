// The bounds a user can see: each is an error naming file:line, the key and the reason,
// never a crash or a silent accept. One behaviour per test case; the values just inside
// each bound are accepted.
#include <catch2/catch.hpp>

#include <string>

#include "common/config/config.hpp"
#include "config_test_support.hpp"

using deif::Config;
using deif::ParseConfig;
using deif_test::ErrorOf;
using deif_test::ExpectError;

namespace {

// "section:\n  key: value\n": the value is on line 2.
std::string One(const std::string& section, const std::string& key, const std::string& value) {
  return section + ":\n  " + key + ": " + value + "\n";
}

}  // namespace

TEST_CASE("agents.count is 2..512", "[config][bounds]") {
  ExpectError(One("agents", "count", "1"), 2, "agents.count", "must be in 2..512 (got 1)");
  ExpectError(One("agents", "count", "513"), 2, "agents.count", "must be in 2..512 (got 513)");
  CHECK(ParseConfig(One("agents", "count", "2"), "ok").agents.count == 2);
  CHECK(ParseConfig(One("agents", "count", "512"), "ok").agents.count == 512);
}

TEST_CASE("scenario.steps is 1..10,000,000", "[config][bounds]") {
  ExpectError(One("scenario", "steps", "0"), 2, "scenario.steps", "must be in 1..10000000 (got 0)");
  ExpectError(One("scenario", "steps", "10000001"), 2, "scenario.steps",
              "must be in 1..10000000 (got 10000001)");
  ExpectError(One("scenario", "steps", "99999999999999999999"), 2, "scenario.steps",
              "integer out of range");
  CHECK(ParseConfig(One("scenario", "steps", "10000000"), "ok").scenario.steps == 10000000);
}

TEST_CASE("Every duration in seconds is finite, positive and at most a day", "[config][bounds]") {
  const char* keys[][2] = {{"scenario", "dt_s"},
                           {"scenario", "period_s"},
                           {"network", "liveliness_lease_s"},
                           {"network", "step_timeout_s"},
                           {"network", "start_timeout_s"}};
  for (const auto& key : keys) {
    const std::string dotted = std::string(key[0]) + "." + key[1];
    DYNAMIC_SECTION(dotted) {
      ExpectError(One(key[0], key[1], "1e10"), 2, dotted, "must be > 0 and <= 86400 (got 1e10)");
      ExpectError(One(key[0], key[1], "86400.5"), 2, dotted, "<= 86400");
      ExpectError(One(key[0], key[1], "0"), 2, dotted, "must be > 0");
      ExpectError(One(key[0], key[1], "-1"), 2, dotted, "must be > 0");
      ExpectError(One(key[0], key[1], ".inf"), 2, dotted, "must be a finite number (got .inf)");
      ExpectError(One(key[0], key[1], ".nan"), 2, dotted, "must be a finite number (got .nan)");
      CHECK_NOTHROW(ParseConfig(One(key[0], key[1], "86400"), "ok"));
    }
  }
}

TEST_CASE("The participant lease and announcement are at most a day", "[config][bounds]") {
  ExpectError(One("network", "participant_lease_s", "1e10"), 2, "network.participant_lease_s",
              "must be > 0 and <= 86400 (got 1e10)");
  ExpectError("network:\n  participant_lease_s: 86400\n  participant_announcement_s: 1e5\n", 3,
              "network.participant_announcement_s", "must be > 0 and <= 86400 (got 1e5)");
  const Config c = ParseConfig(
      "network:\n  participant_lease_s: 86400\n  participant_announcement_s: 3600\n", "ok");
  CHECK(c.network.participant_lease_s == 86400.0);
}

TEST_CASE("Coordinates, radii and velocities are at most 1e6 in magnitude", "[config][bounds]") {
  ExpectError(One("target", "start_m", "[1e7, 0]"), 2, "target.start_m[0]",
              "must be >= -1000000 and <= 1000000 (got 1e7)");
  ExpectError(One("target", "velocity_mps", "[0, -2e6]"), 2, "target.velocity_mps[1]",
              "(got -2e6)");
  ExpectError(One("agents", "initial_centre_m", "[1000001, 0]"), 2, "agents.initial_centre_m[0]",
              "<= 1000000");
  ExpectError(One("filter", "initial_estimate_m", "[0, -1e300]"), 2,
              "filter.initial_estimate_m[1]", ">= -1000000");
  ExpectError(One("agents", "radius_m", "2e6"), 2, "agents.radius_m",
              "must be > 0 and <= 1000000 (got 2e6)");
  ExpectError(One("target", "circle_radius_m", "1e9"), 2, "target.circle_radius_m", "<= 1000000");
  ExpectError(One("agents", "max_speed_mps", "1e7"), 2, "agents.max_speed_mps", "<= 1000000");
  ExpectError(One("sensing", "r1_m", "1e7"), 2, "sensing.r1_m", "<= 1000000, or .inf");
  const Config c = ParseConfig(
      "target: {start_m: [1e6, -1e6], velocity_mps: [-1e6, 1e6]}\nagents: {radius_m: 1e6}\n",
      "ok");
  CHECK(c.target.trajectory.start_m == deif::Vector2(1e6, -1e6));
  CHECK(c.agents.radius_m == 1e6);
}

TEST_CASE("Variances are > 0 and at most 1e6", "[config][bounds]") {
  const char* keys[][2] = {{"target", "range_noise_variance_m2"},
                           {"filter", "process_noise"},
                           {"filter", "range_variance_m2"},
                           {"filter", "initial_position_variance_m2"},
                           {"filter", "initial_velocity_variance_m2ps2"}};
  for (const auto& key : keys) {
    const std::string dotted = std::string(key[0]) + "." + key[1];
    DYNAMIC_SECTION(dotted) {
      ExpectError(One(key[0], key[1], "0"), 2, dotted, "must be > 0 and <= 1000000 (got 0)");
      ExpectError(One(key[0], key[1], "-1e-3"), 2, dotted, "(got -1e-3)");
      ExpectError(One(key[0], key[1], "1.5e6"), 2, dotted, "(got 1.5e6)");
      CHECK_NOTHROW(ParseConfig(One(key[0], key[1], "1e6"), "ok"));
      CHECK_NOTHROW(ParseConfig(One(key[0], key[1], "1e-300"), "ok"));
    }
  }
}

TEST_CASE("The target's perturbation variance may be 0 but not above 1e6", "[config][bounds]") {
  CHECK(ParseConfig(One("target", "process_noise_variance_m2", "0"), "ok")
            .target.trajectory.process_noise_variance == 0.0);
  ExpectError(One("target", "process_noise_variance_m2", "2e6"), 2,
              "target.process_noise_variance_m2", "must be >= 0 and <= 1000000 (got 2e6)");
}

TEST_CASE("The seed is a non-negative decimal integer below 2^64", "[config][bounds]") {
  for (const char* bad : {"-1", "0x20", "1e3", "yes", "18446744073709551616", "1.0", "+5", "01"}) {
    DYNAMIC_SECTION(bad) {
      ExpectError(One("scenario", "seed", bad), 2, "scenario.seed",
                  std::string("expected a non-negative integer below 2^64 (got '") + bad + "')");
    }
  }
  ExpectError(One("scenario", "seed", "\"5\""), 2, "scenario.seed", "the quoted string '5'");
  CHECK(ParseConfig(One("scenario", "seed", "0"), "ok").scenario.seed == 0U);
  CHECK(ParseConfig(One("scenario", "seed", "18446744073709551615"), "ok").scenario.seed ==
        18446744073709551615ULL);
}

TEST_CASE("A boolean given for a number is reported as the user wrote it", "[config][bounds]") {
  ExpectError(One("scenario", "steps", "yes"), 2, "scenario.steps", "expected an integer (got 'yes')");
  ExpectError(One("scenario", "dt_s", "on"), 2, "scenario.dt_s", "expected a number (got 'on')");
  ExpectError(One("agents", "count", "True"), 2, "agents.count", "(got 'True')");
}

TEST_CASE("A boolean key takes true or false only", "[config][bounds]") {
  ExpectError(One("network", "ros2_naming", "yes"), 2, "network.ros2_naming",
              "expected true or false (got 'yes')");
  ExpectError(One("network", "ros2_naming", "1"), 2, "network.ros2_naming", "(got '1')");
  CHECK(ParseConfig(One("network", "ros2_naming", "true"), "ok").network.ros2_naming);
  CHECK_FALSE(ParseConfig(One("network", "ros2_naming", "False"), "ok").network.ros2_naming);
}

TEST_CASE("scenario.name is printable UTF-8 of 1..128 characters", "[config][bounds]") {
  ExpectError(One("scenario", "name", "\"\""), 2, "scenario.name",
              "must be 1..128 characters long (got 0)");
  ExpectError(One("scenario", "name", std::string(129, 'x')), 2, "scenario.name",
              "must be 1..128 characters long (got 129)");
  ExpectError(One("scenario", "name", "\"tab\\there\""), 2, "scenario.name",
              "must be printable (control character U+0009 at character 4)");
  ExpectError(One("scenario", "name", "\"bell\\a\""), 2, "scenario.name", "U+0007");
  ExpectError(One("scenario", "name", "\"line\\nbreak\""), 2, "scenario.name", "U+000A");
  ExpectError(One("scenario", "name", "{a: 1}"), 2, "scenario.name",
              "expected a string (got a mapping)");
  std::string accented;
  for (int i = 0; i < 128; ++i) accented += "\xC3\xA9";  // 128 characters, 256 bytes
  CHECK(ParseConfig(One("scenario", "name", accented), "ok").scenario.name == accented);
  CHECK(ParseConfig(One("scenario", "name", "\"Zürich ✓ run: 1\""), "ok").scenario.name ==
        "Zürich ✓ run: 1");
}

TEST_CASE("network.history_steps is 1..1000", "[config][bounds]") {
  ExpectError(One("network", "history_steps", "0"), 2, "network.history_steps",
              "must be in 1..1000 (got 0)");
  ExpectError(One("network", "history_steps", "1001"), 2, "network.history_steps",
              "must be in 1..1000 (got 1001)");
  CHECK(ParseConfig(One("network", "history_steps", "1000"), "ok").network.history_steps == 1000);
}

TEST_CASE("network.fusion_window_steps is 0..1000", "[config][bounds]") {
  ExpectError(One("network", "fusion_window_steps", "-1"), 2, "network.fusion_window_steps",
              "must be in 0..1000 (got -1)");
  ExpectError(One("network", "fusion_window_steps", "1001"), 2, "network.fusion_window_steps",
              "must be in 0..1000 (got 1001)");
  CHECK(ParseConfig(One("network", "fusion_window_steps", "0"), "ok").network.fusion_window_steps ==
        0);
}

TEST_CASE("network.liveliness_assertions_per_lease is 1..100", "[config][bounds]") {
  ExpectError(One("network", "liveliness_assertions_per_lease", "0"), 2,
              "network.liveliness_assertions_per_lease", "must be in 1..100 (got 0)");
  ExpectError(One("network", "liveliness_assertions_per_lease", "101"), 2,
              "network.liveliness_assertions_per_lease", "must be in 1..100 (got 101)");
  CHECK(ParseConfig(One("network", "liveliness_assertions_per_lease", "100"), "ok")
            .network.liveliness_assertions_per_lease == 100);
}

TEST_CASE("network.deadline_fraction is in (0, 1]", "[config][bounds]") {
  ExpectError(One("network", "deadline_fraction", "0"), 2, "network.deadline_fraction",
              "must be > 0 and <= 1 (got 0)");
  ExpectError(One("network", "deadline_fraction", "1.0001"), 2, "network.deadline_fraction",
              "must be > 0 and <= 1 (got 1.0001)");
  CHECK(ParseConfig(One("network", "deadline_fraction", "1"), "ok").network.deadline_fraction ==
        1.0);
}

TEST_CASE("network.heartbeat_period_s is in [0.001, 10]", "[config][bounds]") {
  ExpectError(One("network", "heartbeat_period_s", "0.0009"), 2, "network.heartbeat_period_s",
              "must be >= 0.001 and <= 10 (got 0.0009)");
  ExpectError(One("network", "heartbeat_period_s", "10.5"), 2, "network.heartbeat_period_s",
              "(got 10.5)");
  CHECK(ParseConfig(One("network", "heartbeat_period_s", "0.001"), "ok")
            .network.heartbeat_period_s == 0.001);
  CHECK(ParseConfig(One("network", "heartbeat_period_s", "10"), "ok").network.heartbeat_period_s ==
        10.0);
}

TEST_CASE("The reliable response delays are in [0, 10] s", "[config][bounds]") {
  ExpectError(One("network", "nack_response_delay_s", "-0.001"), 2,
              "network.nack_response_delay_s", "must be >= 0 and <= 10 (got -0.001)");
  ExpectError(One("network", "heartbeat_response_delay_s", "1e10"), 2,
              "network.heartbeat_response_delay_s", "(got 1e10)");
  CHECK(ParseConfig(One("network", "nack_response_delay_s", "0"), "ok")
            .network.nack_response_delay_s == 0.0);
}

TEST_CASE("network_sim.loss is in [0, 1)", "[config][bounds]") {
  ExpectError(One("network_sim", "loss", "1"), 2, "network_sim.loss", "must be >= 0 and < 1 (got 1)");
  ExpectError(One("network_sim", "loss", "-0.1"), 2, "network_sim.loss", "(got -0.1)");
  CHECK(ParseConfig(One("network_sim", "loss", "0.999"), "ok").network_sim.loss == 0.999);
}

TEST_CASE("network_sim.duplicate and reorder are in [0, 1]", "[config][bounds]") {
  ExpectError(One("network_sim", "duplicate", "1.5"), 2, "network_sim.duplicate",
              "must be >= 0 and <= 1 (got 1.5)");
  ExpectError(One("network_sim", "reorder", "-0.5"), 2, "network_sim.reorder",
              "must be >= 0 and <= 1 (got -0.5)");
  const Config c = ParseConfig("network_sim: {duplicate: 1, reorder: 1}\n", "ok");
  CHECK(c.network_sim.duplicate == 1.0);
  CHECK(c.network_sim.reorder == 1.0);
}

TEST_CASE("network_sim delays are in [0, 86400] s with delay_min_s <= delay_max_s", "[config][bounds]") {
  ExpectError(One("network_sim", "delay_max_s", "1e10"), 2, "network_sim.delay_max_s",
              "must be >= 0 and <= 86400 (got 1e10)");
  ExpectError("network_sim:\n  delay_min_s: 0.2\n  delay_max_s: 0.1\n", 3,
              "network_sim.delay_max_s", "delay_min_s must be <= delay_max_s (got 0.2 > 0.1)");
  ExpectError("network_sim:\n  delay_min_s: 0.2\n", 2, "network_sim.delay_min_s",
              "delay_min_s must be <= delay_max_s (got 0.2 > 0)");
  const Config c = ParseConfig("network_sim: {delay_min_s: 0.01, delay_max_s: 0.01}\n", "ok");
  CHECK(c.network_sim.delay_min_s == 0.01);
}

TEST_CASE("network.discovery_server is host:port with a port in 1..65535", "[config][bounds]") {
  for (const char* bad : {"localhost", "\":11811\"", "\"host:0\"", "\"host:65536\"",
                          "\"host:11811x\"", "\"ho st:11811\"", "\"host:\"", "\"[::1:11811\""}) {
    DYNAMIC_SECTION(bad) {
      ExpectError(One("network", "discovery_server", bad), 2, "network.discovery_server",
                  "must be host:port with a port in 1..65535");
    }
  }
  for (const char* good : {"\"10.0.0.2:11811\"", "\"server.local:1\"", "\"[::1]:65535\""}) {
    CHECK_NOTHROW(ParseConfig(One("network", "discovery_server", good), "ok"));
  }
}

TEST_CASE("sensing.beta is a positive integer up to 64, or -1", "[config][bounds]") {
  ExpectError(One("sensing", "beta", "0"), 2, "sensing.beta",
              "must be a positive integer or -1 (got 0)");
  ExpectError(One("sensing", "beta", "-2"), 2, "sensing.beta", "must be in -1..64 (got -2)");
  ExpectError(One("sensing", "beta", "65"), 2, "sensing.beta", "must be in -1..64 (got 65)");
  ExpectError(One("sensing", "beta", "2.0"), 2, "sensing.beta",
              "expected a positive integer or -1 (got '2.0')");
  CHECK(ParseConfig(One("sensing", "beta", "-1"), "ok").sensing.beta == -1.0);
  CHECK(ParseConfig(One("sensing", "beta", "64"), "ok").sensing.beta == 64.0);
}

TEST_CASE("Integers are decimal without leading zeros", "[config][bounds]") {
  ExpectError(One("agents", "count", "010"), 2, "agents.count",
              "an integer is written without leading zeros (got 010)");
  ExpectError(One("agents", "count", "0x10"), 2, "agents.count", "expected an integer (got '0x10')");
  ExpectError(One("agents", "count", "1e1"), 2, "agents.count", "expected an integer (got '1e1')");
  CHECK(ParseConfig(One("agents", "count", "+3"), "ok").agents.count == 3);
}

TEST_CASE("Numbers are decimal and within double range", "[config][bounds]") {
  ExpectError(One("scenario", "dt_s", "0x1p-3"), 2, "scenario.dt_s", "expected a number (got '0x1p-3')");
  ExpectError(One("scenario", "dt_s", "inf"), 2, "scenario.dt_s", "expected a number (got 'inf')");
  ExpectError(One("scenario", "dt_s", "1e400"), 2, "scenario.dt_s", "number out of range (got 1e400)");
  ExpectError(One("scenario", "dt_s", "."), 2, "scenario.dt_s", "expected a number (got '.')");
  ExpectError(One("scenario", "dt_s", "1_000"), 2, "scenario.dt_s", "expected a number");
  CHECK(ParseConfig(One("scenario", "dt_s", "+.25"), "ok").scenario.dt_s == 0.25);
  CHECK(ParseConfig(One("scenario", "dt_s", "5."), "ok").scenario.dt_s == 5.0);
}

TEST_CASE("Agent ids in faults and partitions are checked against agents.count", "[config][bounds]") {
  ExpectError("faults:\n  - {step: 1, action: kill, agent: 99999999999}\n", 2, "faults[0].agent",
              "integer out of range");
  ExpectError("faults:\n  - {step: 1, action: kill, agent: -3}\n", 2, "faults[0].agent",
              "agent id must be in 1..4 (got -3)");
  ExpectError("network_sim:\n  partitions: [{from_step: 1, to_step: 2, group: [0]}]\n", 2,
              "network_sim.partitions[0].group[0]", "agent id must be in 1..4 (got 0)");
}
