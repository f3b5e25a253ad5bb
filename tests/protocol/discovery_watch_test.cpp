// Endpoint discovery that stops short (docs/FASTDDS_NOTES.md).
#include <catch2/catch.hpp>

#include "common/protocol/discovery_watch.hpp"

using deif::protocol::DiscoveryWatch;

TEST_CASE("Matching short of what is up counts as stopped only after the patience, unchanged",
          "[discovery]") {
  DiscoveryWatch watch(5.0);
  CHECK_FALSE(watch.Stalled(16, 9, 0, 0.0));
  CHECK_FALSE(watch.Stalled(16, 9, 0, 4.9));
  CHECK(watch.Stalled(16, 9, 0, 5.0));
  CHECK(watch.Stalled(16, 9, 0, 30.0));
}

TEST_CASE("Matching that goes on, or participants that come and go, start the patience again",
          "[discovery]") {
  DiscoveryWatch watch(5.0);
  CHECK_FALSE(watch.Stalled(16, 3, 0, 0.0));
  CHECK_FALSE(watch.Stalled(16, 8, 0, 4.0));   // more matched: under way
  CHECK_FALSE(watch.Stalled(16, 8, 0, 8.9));
  CHECK_FALSE(watch.Stalled(17, 8, 0, 9.0));   // one more participant up
  CHECK_FALSE(watch.Stalled(17, 8, 0, 13.9));
  CHECK(watch.Stalled(17, 8, 0, 14.0));
  CHECK_FALSE(watch.Stalled(17, 9, 0, 14.5));  // a late match after all
}

TEST_CASE("Endpoints still being heard of anywhere start the patience again", "[discovery]") {
  // A target that makes one writer of ranges per agent, slowly under a storm of discovery:
  // this agent's writer is not there yet, but the others keep appearing.
  DiscoveryWatch watch(5.0);
  std::uint64_t heard = 300;
  for (double t = 0.0; t < 60.0; t += 0.5) {
    CHECK_FALSE(watch.Stalled(257, 256, ++heard, t));
  }
  // Then nothing more is heard of: a hole after all.
  CHECK_FALSE(watch.Stalled(257, 256, heard, 64.4));  // the last one heard of at 59.5
  CHECK(watch.Stalled(257, 256, heard, 64.5));
}

TEST_CASE("The transport is looked at every half second, and never after giving up", "[discovery]") {
  DiscoveryWatch watch(5.0);
  CHECK(watch.Due(0.0));
  CHECK_FALSE(watch.Due(0.3));
  CHECK(watch.Due(0.5));
  watch.GiveUp();
  CHECK_FALSE(watch.Due(100.0));
}

TEST_CASE("Matching complete, or beyond what is up, is never stopped short", "[discovery]") {
  DiscoveryWatch watch(1.0);
  for (double t = 0.0; t < 10.0; t += 0.5) {
    CHECK_FALSE(watch.Stalled(16, 16, 0, t));
  }
  // A peer restarted in place: its old writer still matched beside the new one.
  for (double t = 10.0; t < 20.0; t += 0.5) {
    CHECK_FALSE(watch.Stalled(16, 17, 0, t));
  }
  CHECK_FALSE(watch.Stalled(0, 0, 0, 30.0));
}

// Forgotten by the server (docs/FASTDDS_NOTES.md).
using deif::protocol::SilenceWatch;

TEST_CASE("Silence counts as forgotten once the server was found again and still nothing came",
          "[discovery]") {
  SilenceWatch watch;
  CHECK_FALSE(watch.Forgotten(100.0, 6.0, 50.0));  // nothing heard yet: the run has not begun
  watch.Heard(10.0);
  // The server listed since before the last sample: a cut shorter than the server's lease,
  // or a target that died. However long, not the server's forgetting.
  CHECK_FALSE(watch.Forgotten(40.0, 6.0, 2.0));
  // The server dropped (its lease ran out: it no longer sends to this client) and found again
  // at 30.6: from then on the silence counts.
  CHECK_FALSE(watch.Forgotten(30.7, 6.0, std::nullopt));
  CHECK_FALSE(watch.Forgotten(36.6, 6.0, 30.6));
  CHECK_FALSE(watch.Forgotten(36.7, 6.0, std::nullopt));  // the peers not listed: told so
  CHECK(watch.Forgotten(36.7, 6.0, 30.6));
  CHECK_FALSE(watch.Forgotten(40.0, 6.0, 30.6));  // said once for this silence
}

TEST_CASE("A host cut off that finds the server again and hears its peers is not forgotten",
          "[discovery]") {
  SilenceWatch watch;
  watch.Heard(10.0);
  CHECK_FALSE(watch.Forgotten(31.0, 6.0, 30.0));  // the heal: the server found again at 30
  watch.Heard(31.5);                              // and the peers heard 1.5 s later
  CHECK_FALSE(watch.Forgotten(40.0, 6.0, 30.0));
  CHECK(watch.silent_s(40.0) == Approx(8.5));
}

TEST_CASE("A watch that gave up says nothing more", "[discovery]") {
  SilenceWatch watch;
  watch.Heard(0.0);
  watch.GiveUp();
  CHECK_FALSE(watch.Forgotten(100.0, 6.0, 50.0));
}
