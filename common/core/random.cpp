#include "common/core/random.hpp"

#include "common/core/types.hpp"

#include <cmath>

namespace deif {
namespace {

constexpr std::uint64_t kGoldenGamma = 0x9E3779B97F4A7C15ULL;  // SplitMix64 increment

// Which of the uniforms behind a draw: the public uniform and the two Box-Muller inputs
// come from disjoint hashes so that they are independent of one another.
enum class Component : std::uint64_t { kUniform = 0, kBoxMullerRadius = 1, kBoxMullerAngle = 2 };

// Folds one more word into a running hash: a SplitMix64 step keyed by the word.
std::uint64_t Absorb(std::uint64_t hash, std::uint64_t word) {
  return MixBits(hash ^ MixBits(word + kGoldenGamma));
}

std::uint64_t HashOf(std::uint64_t seed, NoiseStream stream, std::int64_t step,
                     std::uint64_t index, Component component) {
  std::uint64_t hash = MixBits(seed + kGoldenGamma);
  hash = Absorb(hash, static_cast<std::uint64_t>(stream));
  hash = Absorb(hash, static_cast<std::uint64_t>(step));
  hash = Absorb(hash, index);
  hash = Absorb(hash, static_cast<std::uint64_t>(component));
  return hash;
}

// The top 53 bits as a double in [0, 1), plus half an ulp: in (0, 1), never 0 or 1.
double ToOpenUnitInterval(std::uint64_t bits) {
  constexpr double kTwoToMinus53 = 1.0 / 9007199254740992.0;  // 2^-53
  return (static_cast<double>(bits >> 11) + 0.5) * kTwoToMinus53;
}

}  // namespace

std::uint64_t MixBits(std::uint64_t x) {
  x = (x ^ (x >> 30)) * 0xBF58476D1CE4E5B9ULL;
  x = (x ^ (x >> 27)) * 0x94D049BB133111EBULL;
  return x ^ (x >> 31);
}

double UniformDraw(std::uint64_t seed, NoiseStream stream, std::int64_t step,
                   std::uint64_t index) {
  return ToOpenUnitInterval(HashOf(seed, stream, step, index, Component::kUniform));
}

double StandardNormalDraw(std::uint64_t seed, NoiseStream stream, std::int64_t step,
                          std::uint64_t index) {
  const double u1 =
      ToOpenUnitInterval(HashOf(seed, stream, step, index, Component::kBoxMullerRadius));
  const double u2 =
      ToOpenUnitInterval(HashOf(seed, stream, step, index, Component::kBoxMullerAngle));
  // Box-Muller: u1 in (0, 1) so the logarithm is finite.
  return std::sqrt(-2.0 * std::log(u1)) * std::cos(kTwoPi * u2);
}

}  // namespace deif
