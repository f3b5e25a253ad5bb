// The messages of the step protocol as plain structs (docs/PROTOCOL.md). The DDS layer
// converts them to and from the wire types of idl/deif.idl in one place (dds/conversions);
// the in-process simulation passes them as they are. Nothing here knows about transport.
#pragma once

#include <array>
#include <cstddef>
#include <cstdint>
#include <string>
#include <vector>

#include "common/core/filters.hpp"
#include "common/core/types.hpp"

namespace deif::protocol {

// The identity of one run. Every message carries it; processes of another run on the same
// DDS domain are ignored (docs/PROTOCOL.md, "Runs are isolated").
using RunToken = std::uint64_t;

// The run token of a run name (FNV-1a, 64 bits). Never 0.
RunToken RunTokenOf(const std::string& run_name);

// The identity of one sender of messages: a DDS writer's GUID (16 bytes), or a node of the
// simulated network. Opaque to the protocol: it only compares them, whole or by process.
using SenderKey = std::array<std::uint8_t, 16>;
std::string ToString(const SenderKey& key);
// Whether two keys belong to one process: their first 12 bytes, a DDS GUID prefix (one
// participant), are equal. The scripted and simulated networks key their nodes the same way.
bool SameProcess(const SenderKey& a, const SenderKey& b);

// deif/range: target -> agent `agent_id`, one per agent id and step. `measured` says whether
// the target measured this agent at this step; the roll call lists every id it measured
// (ascending), so every agent knows the complete set of contributions a step should have.
struct RangeMsg {
  RunToken run = 0;
  AgentId agent_id = 0;
  StepIndex step = 0;
  double t_s = 0.0;
  bool measured = false;
  double range_m = 0.0;
  double variance_m2 = 0.0;           // R_j the filter uses
  Vector2 p_sensor = Vector2::Zero();  // the position the range was measured from
  std::vector<AgentId> roll_call;      // ids measured at this step, ascending
};

// deif/contribution: agent -> agents, one per agent and step. Carries (i_j, I_j) of eqs
// (4.49)-(4.50), the position the range was measured from (the sender's place in the ring of
// this step) and the sender's posterior of step-1 in information form, on which the
// contribution was linearised (its prediction is the linearisation point). An empty
// contribution (i = 0, I = 0) says "measured, but no information" (e.g. the range failed the
// innovation gate) so that nobody waits for it.
struct ContributionMsg {
  RunToken run = 0;
  AgentId agent_id = 0;
  std::uint64_t instance_token = 0;  // random per process start
  StepIndex step = 0;
  InfoVector info_vector = InfoVector::Zero();  // i_j
  InfoMatrix info_matrix = InfoMatrix::Zero();  // I_j, all four entries
  Vector2 p_sensor = Vector2::Zero();
  InfoState basis;               // the sender's y(k-1|k-1), Y(k-1|k-1)
  bool merge_request = false;    // the sender's history lost information (docs/PROTOCOL.md)
};

// A contribution as a relay of the tree exchange forwards it (docs/SCALING.md): unchanged,
// with the key of the writer of deif/contribution of the agent that made it, so that the
// receiver binds and tracks that agent exactly as when the contribution comes direct.
struct RelayedContribution {
  SenderKey origin{};
  ContributionMsg msg;
};

// deif/relay_up (to the sender's parent) and deif/relay_down (to its children): a batch of
// contributions of the tree exchange. `step` says that the sender's batches now hold every
// contribution of step `step` the sender was waiting for (up: of its subtree; down: of
// every member), 0 for a batch of late ones.
struct BatchMsg {
  RunToken run = 0;
  AgentId sender_id = 0;
  StepIndex step = 0;
  bool down = false;  // the topic it travels on (not a field on the wire)
  std::vector<RelayedContribution> items;
};
// Most contributions in one batch sample (the bound of idl/deif.idl).
inline constexpr std::size_t kMaxBatchItems = 256;
// Most contributions a relay puts in one sample; more go in several. About 18 KB: over UDP
// one datagram of at most 13 IP fragments (a batch of 128, 36 KB, between 4 hosts lost
// whole datagrams under load and steps with them; docs/SCALING.md).
inline constexpr std::size_t kSentBatchItems = 64;

// deif/agent_state: agent -> target (and observers), one per agent and step.
struct StateMsg {
  RunToken run = 0;
  AgentId agent_id = 0;
  std::uint64_t instance_token = 0;
  StepIndex step = 0;
  Vector2 position_m = Vector2::Zero();
  double angle_rad = 0.0;               // about the agent's own estimate
  Vector2 estimate_m = Vector2::Zero();  // x(k|k), position part
  Matrix2 covariance = Matrix2::Identity();
  int alive = 0;                        // members this agent believes alive, itself included
  int fused = 0;                        // contributions in this step's sum
  bool complete = false;                // the sum holds every contribution of the roll call
  std::int64_t deadline_misses = 0;     // steps finished incomplete so far
  std::int64_t rejected = 0;
  std::int64_t dropped = 0;
  int matched = -1;                     // peers' contribution writers matched (-1: unknown)
};

// deif/truth: target -> observers (logging and metrics only; agents never read it).
struct TruthMsg {
  RunToken run = 0;
  StepIndex step = 0;
  double t_s = 0.0;
  Vector2 p_true = Vector2::Zero();
};

}  // namespace deif::protocol
