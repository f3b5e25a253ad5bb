#include <catch2/catch.hpp>

#include <cmath>
#include <cstdint>

#include "common/core/random.hpp"

namespace deif {
namespace {

constexpr std::uint64_t kSeed = 20240607;

TEST_CASE("A draw is a pure function of seed, stream, step and index", "[random]") {
  // GIVEN the same inputs twice, with other draws in between
  const double first = StandardNormalDraw(kSeed, NoiseStream::kRangeNoise, 17, 3);
  (void)StandardNormalDraw(kSeed, NoiseStream::kRangeNoise, 18, 3);
  (void)UniformDraw(kSeed, NoiseStream::kTargetProcess, 17, 3);
  const double second = StandardNormalDraw(kSeed, NoiseStream::kRangeNoise, 17, 3);
  // THEN the draws are bit-identical
  CHECK(first == second);
  CHECK(UniformDraw(kSeed, NoiseStream::kTargetProcess, 5, 1) ==
        UniformDraw(kSeed, NoiseStream::kTargetProcess, 5, 1));
}

TEST_CASE("Changing the seed, stream, step or index changes the draw", "[random]") {
  const double base = StandardNormalDraw(kSeed, NoiseStream::kRangeNoise, 10, 2);
  CHECK(StandardNormalDraw(kSeed + 1, NoiseStream::kRangeNoise, 10, 2) != base);
  CHECK(StandardNormalDraw(kSeed, NoiseStream::kTargetProcess, 10, 2) != base);
  CHECK(StandardNormalDraw(kSeed, NoiseStream::kRangeNoise, 11, 2) != base);
  CHECK(StandardNormalDraw(kSeed, NoiseStream::kRangeNoise, 10, 3) != base);
  CHECK(UniformDraw(kSeed, NoiseStream::kRangeNoise, 10, 2) !=
        UniformDraw(kSeed, NoiseStream::kRangeNoise, 10, 3));
}

TEST_CASE("Uniform draws lie strictly inside (0, 1) with mean 1/2", "[random]") {
  constexpr int kDraws = 100000;
  double sum = 0.0;
  for (int k = 0; k < kDraws; ++k) {
    const double u = UniformDraw(kSeed, NoiseStream::kTargetProcess, k, 0);
    REQUIRE(u > 0.0);
    REQUIRE(u < 1.0);
    sum += u;
  }
  // The standard error of the mean of U(0, 1) is sqrt(1/12 / n) = 9.1e-4 for n = 1e5;
  // 5 standard errors = 4.6e-3.
  const double mean = sum / static_cast<double>(kDraws);
  CHECK(std::abs(mean - 0.5) < 5.0 * std::sqrt(1.0 / 12.0 / static_cast<double>(kDraws)));
}

TEST_CASE("Standard normal draws have zero mean and unit variance", "[random]") {
  constexpr int kDraws = 100000;
  double sum = 0.0;
  double sum_sq = 0.0;
  for (int k = 0; k < kDraws; ++k) {
    // Spread over steps and indices, as the simulation uses them.
    const double z = StandardNormalDraw(kSeed, NoiseStream::kRangeNoise, k / 10,
                                        static_cast<std::uint64_t>(k % 10));
    sum += z;
    sum_sq += z * z;
  }
  const double n = static_cast<double>(kDraws);
  const double mean = sum / n;
  const double variance = sum_sq / n - mean * mean;
  // Standard errors for n = 1e5: mean 1/sqrt(n) = 3.2e-3; variance sqrt(2/n) = 4.5e-3
  // (for a normal, Var(s^2) = 2 sigma^4 / n). Allow 5 standard errors.
  CHECK(std::abs(mean) < 5.0 / std::sqrt(n));
  CHECK(std::abs(variance - 1.0) < 5.0 * std::sqrt(2.0 / n));
}

TEST_CASE("Normal draws at neighbouring steps are uncorrelated", "[random]") {
  constexpr int kDraws = 100000;
  double sum_product = 0.0;
  for (int k = 0; k < kDraws; ++k) {
    sum_product += StandardNormalDraw(kSeed, NoiseStream::kTargetProcess, k, 0) *
                   StandardNormalDraw(kSeed, NoiseStream::kTargetProcess, k + 1, 0);
  }
  // The sample lag-1 autocorrelation of white noise has standard error 1/sqrt(n).
  const double n = static_cast<double>(kDraws);
  CHECK(std::abs(sum_product / n) < 5.0 / std::sqrt(n));
}

}  // namespace
}  // namespace deif
