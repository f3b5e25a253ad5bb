// Counter-based random numbers. A draw is a pure function of (seed, stream, step, index),
// so the in-process simulation and the separate target process produce bit-identical
// noise for the same seed without sharing any generator state.
#pragma once

#include <cstdint>

namespace deif {

enum class NoiseStream : std::uint64_t {
  kRangeNoise = 1,    // index = agent id
  kTargetProcess = 2,  // index = axis (0: x, 1: y)
  kNetwork = 3         // the simulated network's draws (step = draw counter)
};

// SplitMix64 finaliser (Steele, Lea, Flood 2014).
std::uint64_t MixBits(std::uint64_t x);

// Uniform in the open interval (0, 1).
double UniformDraw(std::uint64_t seed, NoiseStream stream, std::int64_t step, std::uint64_t index);

// Standard normal N(0, 1) by Box-Muller over two independent uniform draws.
double StandardNormalDraw(std::uint64_t seed, NoiseStream stream, std::int64_t step,
                          std::uint64_t index);

}  // namespace deif
