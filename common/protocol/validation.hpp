// Validation of every message a process receives, before it can touch an estimate, a ring
// or a step (docs/ARCHITECTURE.md, "Peer data is untrusted"). Pure functions: each returns
// nullptr when the message is acceptable, or a short snake_case reason that is counted and
// logged once per peer and reason.
#pragma once

#include "common/config/config.hpp"
#include "common/protocol/messages.hpp"

namespace deif::protocol {

// Plausibility limits shared by every check.
inline constexpr double kMaxCoordinateM = 1e6;   // |x|, |y| of any position [m]
inline constexpr double kMaxRangeM = 1e6;        // a range [m]
inline constexpr double kMinVarianceM2 = 1e-12;  // R [m^2]: below this I_j = H^T R^-1 H explodes
inline constexpr double kMaxVarianceM2 = 1e6;

// A range for agent `self` from the target. A noisy range may be negative; its magnitude is
// bounded.
const char* ValidateRange(const RangeMsg& msg, const Config& config, AgentId self);
// Whether a ValidateRange reason concerns only the measured value (the message itself, its
// step and roll call, are sound): the step goes on without this measurement.
bool IsMeasurementReason(const char* reason);
// A contribution from a peer (identity is checked by the protocol, not here).
const char* ValidateContributionMsg(const ContributionMsg& msg, const Config& config);
// An agent's state, as the target receives it.
const char* ValidateState(const StateMsg& msg, const Config& config);

bool IsFinitePosition(const Vector2& p);
bool ValidAgentId(AgentId id, const Config& config);

}  // namespace deif::protocol
