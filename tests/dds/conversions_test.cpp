// The conversion of a peer's contribution from the wire (dds/conversions.cpp): the basis
// (y, Y) takes the sizes 2 and 4 only, whatever basis_dim says, because the state types hold
// at most 4 (common/core/types.hpp); any other is left empty, which validation refuses.
#include <catch2/catch.hpp>

#include <array>

#include "common/core/types.hpp"
#include "dds/conversions.hpp"

namespace {

deif_msgs::Contribution WireContribution(int basis_dim) {
  deif_msgs::Contribution c;
  c.agent_id(3);
  c.step(7);
  c.basis_dim(basis_dim);
  std::array<double, 4> y{1.0, 2.0, 3.0, 4.0};
  std::array<double, 16> Y{};
  for (std::size_t i = 0; i < Y.size(); ++i) Y[i] = static_cast<double>(i);
  c.basis_vector(y);
  c.basis_matrix(Y);
  return c;
}

}  // namespace

TEST_CASE("A peer's basis is taken in 2 or 4 dimensions only", "[dds]") {
  SECTION("2 and 4: the first entries, row-major") {
    for (int dim : {2, 4}) {
      const deif::protocol::ContributionMsg m = deif::dds::FromIdl(WireContribution(dim));
      REQUIRE(m.basis.y.size() == dim);
      REQUIRE(m.basis.Y.rows() == dim);
      REQUIRE(m.basis.Y.cols() == dim);
      CHECK(m.basis.y(dim - 1) == static_cast<double>(dim));
      CHECK(m.basis.Y(1, 0) == static_cast<double>(dim));  // entry dim of the row-major array
    }
  }
  SECTION("any other: left empty") {
    for (int dim : {-1, 0, 1, 3, 5, 16, 1 << 30}) {
      const deif::protocol::ContributionMsg m = deif::dds::FromIdl(WireContribution(dim));
      CHECK(m.basis.y.size() == 0);
      CHECK(m.basis.Y.size() == 0);
    }
  }
  CHECK(deif::kMaxStateDim == 4);  // what the wire's arrays hold (idl/deif.idl)
}
