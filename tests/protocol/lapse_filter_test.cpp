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

namespace {
// A lapse of `writer` at t that outlasts the filter's grace: reported, then due.
void LoseAt(LapseFilter& filter, const SenderKey& writer, double t) {
  REQUIRE_FALSE(filter.Report(writer, false, t).has_value());
  const double due_s = *filter.NextDue();
  const auto due = filter.Due(due_s);
  REQUIRE(due.size() == 1);
  REQUIRE(due[0] == writer);
}
}  // namespace

TEST_CASE("A loss undone soon after doubles the grace, up to 8 x and the cap", "[protocol][lapse]") {
  LapseFilter filter(0.2, 5.0);
  CHECK(filter.grace_factor() == 1.0);
  LoseAt(filter, Writer(1), 10.0);  // due at 10.2
  const auto back = filter.Report(Writer(1), true, 10.21);  // a renewal just after: undone
  REQUIRE(back.has_value());
  CHECK(*back);  // still acted on: the loss was
  CHECK(filter.losses_undone() == 1);
  CHECK(filter.grace_factor() == 2.0);
  // Every writer's lapse is held twice as long now.
  CHECK_FALSE(filter.Report(Writer(2), false, 11.0).has_value());
  CHECK(filter.NextDue() == Approx(11.4));
  CHECK(filter.Due(11.39).empty());
  CHECK_FALSE(filter.Report(Writer(2), true, 11.39).has_value());  // within the longer grace
  for (double t : {12.0, 13.0, 14.0, 15.0}) {
    LoseAt(filter, Writer(3), t);
    filter.Report(Writer(3), true, t + 0.9);
  }
  CHECK(filter.losses_undone() == 5);
  CHECK(filter.grace_factor() == LapseFilter::kMaxFactor);
  CHECK(filter.GraceNow(0.2) == Approx(1.6));
  CHECK(filter.GraceNow(1.0) == Approx(5.0));  // no longer than the cap
  CHECK(filter.GraceNow(6.0) == Approx(6.0));  // a grace above the cap stays as it is
}

TEST_CASE("A writer back long after its loss, or never lost, leaves the grace as it is", "[protocol][lapse]") {
  LapseFilter filter(0.2, 5.0);
  LoseAt(filter, Writer(1), 10.0);
  // Back after the window (4 x its grace, at least 1 s): it was gone for a while (frozen,
  // restarted, cut off), which says nothing of the network's renewals.
  filter.Report(Writer(1), true, 10.2 + 1.01);
  CHECK(filter.losses_undone() == 0);
  CHECK(filter.grace_factor() == 1.0);
  // A lapse forgiven within the grace: not a loss, so not an undone one.
  filter.Report(Writer(2), false, 20.0);
  filter.Report(Writer(2), true, 20.1);
  CHECK(filter.losses_undone() == 0);
  // A loss confirmed by other means (its process ended): a return is a new writer's matter.
  filter.Report(Writer(3), false, 30.0);
  CHECK(filter.Confirm(Writer(3)));
  filter.Report(Writer(3), true, 30.05);
  CHECK(filter.grace_factor() == 1.0);
}

TEST_CASE("The grown grace halves after each quiet minute", "[protocol][lapse]") {
  LapseFilter filter(0.2, 5.0);
  for (double t : {10.0, 20.0}) {
    LoseAt(filter, Writer(1), t);
    filter.Report(Writer(1), true, t + 0.5);
  }
  CHECK(filter.grace_factor() == 4.0);  // the last at 20.5
  filter.Report(Writer(2), false, 20.5 + LapseFilter::kQuietS - 0.1);
  CHECK(filter.grace_factor() == 4.0);
  filter.Due(20.5 + LapseFilter::kQuietS);
  CHECK(filter.grace_factor() == 2.0);
  filter.Due(20.5 + 2 * LapseFilter::kQuietS + 0.1);
  CHECK(filter.grace_factor() == 1.0);
  filter.Due(20.5 + 10 * LapseFilter::kQuietS);
  CHECK(filter.grace_factor() == 1.0);
}

TEST_CASE("Without a cap above it, or with a grace of 0, the grace never grows", "[protocol][lapse]") {
  LapseFilter fixed(0.2);
  LoseAt(fixed, Writer(1), 10.0);
  fixed.Report(Writer(1), true, 10.25);
  CHECK(fixed.losses_undone() == 1);  // counted all the same
  CHECK(fixed.GraceNow(0.2) == Approx(0.2));
  LapseFilter none(0.0, 5.0);
  for (double t : {10.0, 11.0}) {
    const auto lost = none.Report(Writer(1), false, t);
    REQUIRE(lost.has_value());  // every lapse a loss, as configured
    CHECK_FALSE(*lost);
    none.Report(Writer(1), true, t + 0.1);
  }
  CHECK(none.GraceNow(0.0) == 0.0);
}
