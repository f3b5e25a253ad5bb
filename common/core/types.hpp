// Fixed-size Eigen aliases and the small value types shared by the whole core.
#pragma once

#include <cstdint>

#include <Eigen/Dense>

namespace deif {

using Vector2 = Eigen::Vector2d;       // a position or displacement in the plane [m]
using Matrix2 = Eigen::Matrix2d;
using RowVector2 = Eigen::RowVector2d;  // the Jacobian of a scalar measurement w.r.t. position

// The information contribution of one sensor lives in the position sub-space: a range
// depends on the target position only, so for any motion model the velocity block of
// I_j and i_j is zero (eqs 4.49-4.50 with H = [dh/dp, 0]).
using InfoVector = Eigen::Vector2d;  // i_j
using InfoMatrix = Eigen::Matrix2d;  // I_j

// The filter state is 2-D for the random walk (eq 5.1) and 4-D [p; v] for the
// constant-velocity model, chosen at run time, so its size really varies; but never
// beyond 4, so it lives inline, not on the heap. Every contribution carries its sender's
// (y, Y) and is copied a few times on its way through a relay: with heap-allocated
// matrices the allocator was a fifth of an agent's CPU at N = 64 (docs/BENCHMARKS.md,
// "Allocations"). Sizes come only from the motion model and from messages checked to be
// 2 or 4 (dds/conversions.cpp).
inline constexpr int kMaxStateDim = 4;
using StateVector = Eigen::Matrix<double, Eigen::Dynamic, 1, 0, kMaxStateDim, 1>;
using StateMatrix = Eigen::Matrix<double, Eigen::Dynamic, Eigen::Dynamic, 0, kMaxStateDim, kMaxStateDim>;

// pi and 2 pi, written once for the whole project.
inline constexpr double kPi = 3.141592653589793238462643383279502884;
inline constexpr double kTwoPi = 2.0 * kPi;

using AgentId = int;
using StepIndex = std::int64_t;

}  // namespace deif
