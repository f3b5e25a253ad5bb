// The lapse filter (docs/PROTOCOL.md, "Slow is not gone").
#include <catch2/catch.hpp>

#include "common/protocol/lapse_filter.hpp"

using deif::protocol::LapseFilter;
using deif::protocol::SenderKey;

namespace {
SenderKey Writer(std::uint8_t n) {
  SenderKey key{};
  key[0] = n;
  return key;
}
}  // namespace

TEST_CASE("A lapse is a loss only once the writer stayed silent for the grace", "[protocol][lapse]") {
  LapseFilter filter(0.2);
  CHECK_FALSE(filter.Report(Writer(1), false, 10.0).has_value());  // held
  CHECK(filter.NextDue() == Approx(10.2));
  CHECK(filter.Due(10.19).empty());
  const auto due = filter.Due(10.2);
  REQUIRE(due.size() == 1);
  CHECK(due[0] == Writer(1));
  CHECK_FALSE(filter.NextDue().has_value());
  // Alive again after the loss was acted on: a return to act on.
  const auto back = filter.Report(Writer(1), true, 11.0);
  REQUIRE(back.has_value());
  CHECK(*back);
  CHECK(filter.ignored() == 0);
}

TEST_CASE("A lapse that ends within the grace is never acted on", "[protocol][lapse]") {
  LapseFilter filter(0.2);
  CHECK_FALSE(filter.Report(Writer(1), false, 10.0).has_value());
  CHECK_FALSE(filter.Report(Writer(1), true, 10.1).has_value());
  CHECK(filter.Due(100.0).empty());
  CHECK(filter.ignored() == 1);
}

TEST_CASE("Held losses come due in the order they lapsed; a repeated report keeps the first",
          "[protocol][lapse]") {
  LapseFilter filter(0.2);
  filter.Report(Writer(2), false, 10.05);
  filter.Report(Writer(1), false, 10.0);
  filter.Report(Writer(1), false, 10.1);  // a second report of the same lapse
  const auto due = filter.Due(10.3);
  REQUIRE(due.size() == 2);
  CHECK(due[0] == Writer(1));
  CHECK(due[1] == Writer(2));
}

TEST_CASE("Confirm ends a held lapse at once; a grace of 0 acts on every lapse", "[protocol][lapse]") {
  LapseFilter filter(0.2);
  filter.Report(Writer(1), false, 10.0);
  CHECK(filter.Confirm(Writer(1)));
  CHECK_FALSE(filter.Confirm(Writer(1)));
  CHECK(filter.Due(100.0).empty());
  LapseFilter none(0.0);
  const auto now = none.Report(Writer(1), false, 10.0);
  REQUIRE(now.has_value());
  CHECK_FALSE(*now);
}

TEST_CASE("After this process was away, lapses count only once they outlast the hold", "[protocol][lapse]") {
  // A process frozen for seconds reads nothing: every peer's writer lapses in its view until
  // the peers' next renewals reach it. With a grace of 0 too.
  for (const double grace : {0.2, 0.0}) {
    LapseFilter filter(grace);
    // Just before it noticed: held for the grace, or (grace 0) a loss at once.
    CHECK(filter.Report(Writer(1), false, 9.9).has_value() == (grace == 0.0));
    filter.HoldUntil(12.0);
    CHECK_FALSE(filter.Report(Writer(2), false, 10.0).has_value());
    CHECK_FALSE(filter.Report(Writer(3), false, 10.5).has_value());
    CHECK(filter.NextDue() == Approx(12.0));
    CHECK_FALSE(filter.Report(Writer(2), true, 11.0).has_value());  // renewed: never lost
    CHECK(filter.Due(11.99).empty());
    const auto due = filter.Due(12.0);  // those that stayed silent: lost
    REQUIRE(due.size() == (grace > 0.0 ? 2u : 1u));
    CHECK(due.back() == Writer(3));
    if (grace > 0.0) CHECK(due.front() == Writer(1));  // held, and due at the hold's end
    // After the hold, the grace alone again.
    const auto later = filter.Report(Writer(4), false, 20.0);
    if (grace > 0.0) {
      CHECK_FALSE(later.has_value());
      CHECK(filter.NextDue() == Approx(20.0 + grace));
    } else {
      REQUIRE(later.has_value());
      CHECK_FALSE(*later);
    }
  }
}

TEST_CASE("A writer's lapse can have a grace of its own", "[protocol][lapse]") {
  LapseFilter filter(0.2);
  CHECK_FALSE(filter.Report(Writer(1), false, 10.0, 1.0).has_value());
  CHECK_FALSE(filter.Report(Writer(2), false, 10.0).has_value());  // the filter's grace
  CHECK(filter.NextDue() == Approx(10.2));
  const auto first = filter.Due(10.5);
  REQUIRE(first.size() == 1);
  CHECK(first[0] == Writer(2));
  CHECK(filter.NextDue() == Approx(11.0));
  CHECK_FALSE(filter.Report(Writer(1), true, 10.9, 1.0).has_value());  // back within its own
  CHECK(filter.ignored() == 1);
  CHECK(filter.Due(100.0).empty());
}
