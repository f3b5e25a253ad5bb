// The document itself: what a YAML parser would crash on, misread or silently accept is an
// error naming file:line (0 when unknown), the key where there is one, and the reason.
#include <catch2/catch.hpp>

#include <string>

#include "common/config/config.hpp"
#include "common/config/document.hpp"
#include "config_test_support.hpp"

using deif::Config;
using deif::ConfigError;
using deif::ParseConfig;
using deif_test::CheckError;
using deif_test::ErrorOf;
using deif_test::ExpectError;
using deif_test::TempFile;

TEST_CASE("An empty document, or one with comments only, is the default scenario", "[config][document]") {
  for (const char* text : {"", "\n\n", "# nothing here\n   # at all\n", "---\n", "~\n"}) {
    DYNAMIC_SECTION(text) {
      const Config c = ParseConfig(text, "empty.yaml");
      CHECK(deif_test::Fingerprint(c) == deif_test::Fingerprint(Config{}));
    }
  }
}

TEST_CASE("A top level that is not a mapping is refused", "[config][document]") {
  ExpectError("- scenario\n- agents\n", 1, "", "the top level must be a mapping of sections");
  ExpectError("\n42\n", 2, "", "the top level must be a mapping of sections (scenario, target");
  ExpectError("\"text\"\n", 1, "", "got the quoted string 'text'");
}

TEST_CASE("YAML merge keys are refused", "[config][document]") {
  ExpectError("scenario:\n  <<: {steps: 3}\n", 2, "scenario",
              "YAML merge keys (<<) are not supported");
  ExpectError("<<: {scenario: {steps: 3}}\n", 1, "", "YAML merge keys (<<) are not supported");
}

TEST_CASE("Duplicate keys are refused at any depth", "[config][document]") {
  ExpectError("scenario: {steps: 3}\nscenario: {steps: 4}\n", 2, "scenario",
              "duplicate key (first at line 1)");
  ExpectError("agents:\n  count: 3\n  count: 4\n", 3, "agents.count",
              "duplicate key (first at line 2)");
  ExpectError("faults:\n  - {step: 5, action: kill, agent: 1}\n  - {step: 6, step: 7}\n", 3,
              "faults[1].step", "duplicate key (first at line 3)");
  ExpectError("network_sim:\n  partitions:\n    - {from_step: 1, to_step: 2, group: [1], group: [2]}\n",
              3, "network_sim.partitions[0].group", "duplicate key");
  // Also inside a section nobody reads: the document is refused before its meaning.
  ExpectError("unknown:\n  a: {b: 1, b: 2}\n", 2, "unknown.a.b", "duplicate key");
}

TEST_CASE("YAML anchors and aliases are refused, so they cannot hide duplicates", "[config][document]") {
  ExpectError("scenario: &s\n  steps: 3\nagents: *s\n", 1, "scenario",
              "YAML anchors (&s) are not supported");
  ExpectError("agents:\n  &k count: 3\n  *k : 4\n", 2, "agents", "YAML anchors (&k) are not supported");
  // An alias without its anchor is the parser's error.
  CheckError(ErrorOf("scenario: *nothing\n"), "bad.yaml", 1, "", "YAML syntax error");
}

TEST_CASE("YAML tags are refused", "[config][document]") {
  ExpectError("scenario:\n  steps: !!int 3\n", 2, "scenario.steps", "YAML tags (!!int) are not supported");
  ExpectError("scenario:\n  name: !!str 12\n", 2, "scenario.name", "YAML tags (!!str)");
  ExpectError("scenario: !custom {steps: 3}\n", 1, "scenario", "YAML tags (!custom)");
}

TEST_CASE("A tab is refused with its line", "[config][document]") {
  ExpectError("scenario:\n\tsteps: 3\n", 2, "", "tab character: indent with spaces, not tabs");
  ExpectError("scenario:\n  steps: 3\t# three\n", 2, "", "tab character");
}

TEST_CASE("A YAML syntax error names its line", "[config][document]") {
  CheckError(ErrorOf("scenario:\n  steps: [1, 2\n  dt_s: 0.1\n"), "bad.yaml", 3, "",
             "YAML syntax error");
  CheckError(ErrorOf("scenario:\n  steps: 3\n dt_s: 0.1\n"), "bad.yaml", 3, "", "YAML syntax error");
  CheckError(ErrorOf("a: 'open\n"), "bad.yaml", 1, "a",
             "YAML syntax error: a quoted string is never closed");
  CheckError(ErrorOf("a: [1, 2\n"), "bad.yaml", 1, "", "YAML syntax error: end of sequence flow");
  CheckError(ErrorOf("a: {b: 1\n"), "bad.yaml", 1, "", "YAML syntax error: end of map flow");
  CHECK(ParseConfig("scenario: {name: 'it''s \\\"closed\\\"'}\n", "ok").scenario.name ==
        "it's \\\"closed\\\"");
}

TEST_CASE("A stray comma at the top level is a syntax error, not endless empty documents", "[config][document]") {
  ExpectError(",a\n", 1, "", "YAML syntax error: unexpected ','");
  ExpectError("# comment\n, scenario: {steps: 3}\n", 2, "", "unexpected ','");
}

TEST_CASE("A second YAML document is refused", "[config][document]") {
  ExpectError("scenario: {steps: 3}\n---\nagents: {count: 3}\n", 2, "", "a second YAML document");
}

TEST_CASE("A NUL byte is refused as not text", "[config][document]") {
  ExpectError(std::string("scenario:\n  steps: 3\0\n", 21), 2, "", "NUL byte: not a text file");
}

TEST_CASE("Bytes that are not UTF-8 are refused with their line", "[config][document]") {
  ExpectError("scenario:\n  name: \"Z\xFCrich\"\n", 2, "", "invalid UTF-8 (byte 0xFC)");
  ExpectError("# fine\n# \xE2\x82\n", 2, "", "starts a truncated sequence");
  ExpectError("# \xC0\xAF\n", 1, "", "invalid UTF-8 (byte 0xC0)");
  ExpectError("# \xED\xA0\x80\n", 1, "", "overlong or surrogate");
  ExpectError("# \xF8\x88\x80\x80\x80\n", 1, "", "invalid UTF-8 (byte 0xF8)");
}

TEST_CASE("A UTF-8 byte order mark and CRLF line ends are accepted", "[config][document]") {
  const Config c = ParseConfig("\xEF\xBB\xBFscenario:\r\n  steps: 7\r\n", "bom.yaml");
  CHECK(c.scenario.steps == 7);
}

TEST_CASE("Control characters are refused", "[config][document]") {
  ExpectError("scenario:\n  name: \"a\x01" "b\"\n", 2, "", "control character U+0001");
  ExpectError("scenario:\n  name: a\x7F\n", 2, "", "control character U+007F");
  ExpectError("scenario:\n  name: \"a\xC2\x9F\"\n", 2, "", "control character U+009F");
  // Escaped in a double-quoted string, it reaches the string's own check.
  ExpectError("scenario:\n  name: \"a\\x85\"\n", 2, "scenario.name",
              "must be printable (control character U+0085 at character 2)");
}

TEST_CASE("A binary file is refused as not text", "[config][document]") {
  const TempFile file("binary", std::string("\x7F" "ELF\x02\x01\x01\0\0\0\0\0", 12));
  CheckError([&] {
    try {
      deif::LoadConfig(file.path());
    } catch (const ConfigError& e) {
      return e;
    }
    FAIL("a binary file was accepted");
    return ConfigError("", "", 0, "");
  }(), file.path(), 1, "", "NUL byte: not a text file");
}

TEST_CASE("A directory given as the config is refused", "[config][document]") {
  const TempFile file("directory", "");
  try {
    deif::LoadConfig(file.dir());
    FAIL("a directory was accepted");
  } catch (const ConfigError& e) {
    CheckError(e, file.dir(), 0, "", "is a directory, not a config file");
  }
}

TEST_CASE("A file over 1 MiB is refused before it is parsed", "[config][document]") {
  std::string text = "scenario:\n  name: x\n";
  text += std::string(deif::kMaxConfigBytes, '#');
  const TempFile file("large", text);
  try {
    deif::LoadConfig(file.path());
    FAIL("a file over the limit was accepted");
  } catch (const ConfigError& e) {
    CheckError(e, file.path(), 0, "", "too large: " + std::to_string(text.size()) + " bytes");
  }
  ExpectError(text, 0, "", "too large");
}

TEST_CASE("Nesting 200 000 levels deep is refused without overflowing the stack", "[config][document]") {
  constexpr int kDepth = 200000;
  const std::string flow_lists = "scenario:\n  name: " + std::string(kDepth, '[') +
                                 std::string(kDepth, ']') + "\n";
  ExpectError(flow_lists, 2, "scenario.name" + [] {
    std::string path;
    for (int i = 0; i < deif::kMaxConfigDepth - 2; ++i) path += "[0]";
    return path;
  }(), "nested deeper than 32 levels");

  std::string flow_maps;
  for (int i = 0; i < kDepth; ++i) flow_maps += "{a: ";
  flow_maps += "1" + std::string(kDepth, '}');
  CHECK_THAT(std::string(ErrorOf(flow_maps).what()), Catch::Contains("nested deeper than 32"));

  std::string block_lists;
  for (int i = 0; i < kDepth; ++i) block_lists += "- ";
  CHECK_THAT(std::string(ErrorOf(block_lists + "x\n").what()),
             Catch::Contains("nested deeper than 32"));

  // Unclosed: refused as well (too deep before the parser reaches the end).
  CHECK_THAT(std::string(ErrorOf(std::string(kDepth, '[')).what()),
             Catch::Contains("nested deeper than 32"));
  CHECK_THAT(std::string(ErrorOf(std::string(kDepth, '{')).what()),
             Catch::Contains("nested deeper than 32"));
}

TEST_CASE("Nesting up to the limit is read", "[config][document]") {
  // A 31-deep list inside an unknown key: read, then refused for its key, not its depth.
  const std::string text = "extra: " + std::string(31, '[') + std::string(31, ']') + "\n";
  ExpectError(text, 1, "extra", "unknown key");
}

TEST_CASE("A key that is not a plain name is refused", "[config][document]") {
  ExpectError("? [a, b]\n: 1\n", 1, "", "keys must be plain names (got a list)");
  ExpectError("scenario:\n  ? {a: 1}\n  : 2\n", 2, "scenario", "keys must be plain names (got a mapping)");
}

TEST_CASE("The document reader keeps lines and quoting", "[config][document]") {
  const deif::DocNode root = deif::ReadDocument("a:\n  b: \"5\"\n  c: 5\n  d:\n", "doc");
  REQUIRE(root.IsMap());
  const deif::DocNode* a = root.Find("a");
  REQUIRE(a != nullptr);
  CHECK(a->Find("b")->quoted);
  CHECK_FALSE(a->Find("c")->quoted);
  CHECK(a->Find("c")->line == 3);
  CHECK(a->Find("d")->IsNull());
  CHECK(a->Find("d")->line == 4);  // an empty value is on its key's line
  CHECK(a->Find("b")->SourceName() == "doc");
}
