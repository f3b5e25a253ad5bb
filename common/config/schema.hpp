// The configuration schema: every key declared once, with its type, default, range, unit,
// description and the Config field it sets (schema.cpp). The parser (config.cpp), the YAML
// output (ToYaml), the visitor below and the reference documentation (reference.hpp,
// docs/CONFIG.md, deif_config --reference-yaml) are all derived from it.
#pragma once

#include <functional>
#include <memory>
#include <optional>
#include <string>
#include <string_view>
#include <vector>

namespace deif {

struct Config;

enum class KeyType {
  kDouble,      // a decimal number (.inf only where allow_infinity)
  kInt,         // an integer (int field)
  kInt64,       // an integer (64-bit field)
  kUint64,      // a non-negative integer below 2^64
  kBool,        // true or false
  kString,      // a string (printable UTF-8)
  kEnum,        // one of enum_names
  kVector2,     // [x, y]
  kDoubleList,  // [a, b, ...]
  kIntList,     // [1, 2, ...]
  kRecordList,  // a list of mappings, each with the keys of `fields`
};

// One end of a number's range.
struct Bound {
  double value = 0.0;
  bool inclusive = true;
};

struct KeyAccess;  // how a key reads and writes its field (schema_access.hpp)

struct KeySpec {
  std::string key;      // dotted: "network.domain_id"; a field of a record: "faults[].step"
  std::string section;  // "network"; "" for a top-level key such as "faults"
  std::string name;     // "domain_id"
  KeyType type = KeyType::kDouble;
  // The default as YAML text (flow style); empty for a record field without a default.
  std::string default_yaml;
  // Numbers, and every element of a list of numbers or of a point.
  std::optional<Bound> min;
  std::optional<Bound> max;
  bool allow_infinity = false;   // kDouble: .inf is allowed too (beyond max)
  std::size_t min_length = 0;    // kString, in characters (code points)
  std::size_t max_length = 0;    // kString; 0: no limit
  std::vector<std::string> enum_names;  // kEnum
  std::string unit;              // "s", "m^2", ...; empty for none
  std::string range_note;        // rules the range does not say ("> r0_m", "host:port")
  std::string expected;          // what a wrong type is told it should be; "" for the type's
  std::string description;       // one paragraph
  bool required = false;         // a record field every element must have
  std::vector<KeySpec> fields;   // kRecordList: the keys of one element
  std::string element_noun;      // kRecordList: "fault" (messages say "every fault needs a step")
  std::shared_ptr<const KeyAccess> access;

  // For the documentation: "number", "integer", "[x, y]", "list of {step, action, agent}", ...
  std::string TypeText() const;
  // For the documentation and messages: "2..512", "(0, 86400]", "> r0_m", ...; "" if none.
  std::string RangeText() const;
};

// A top-level group of keys (a mapping) or a top-level key (faults), in document order.
struct SectionSpec {
  std::string name;
  std::string description;  // one paragraph
  std::vector<const KeySpec*> keys;  // a top-level key: the key itself
  bool is_key = false;               // true for a top-level key such as faults
};

// Every key, in document order (record fields are in their list's `fields`).
const std::vector<KeySpec>& Schema();
// The sections, in document order.
const std::vector<SectionSpec>& Sections();
// A key by its dotted name ("agents.count", "faults", "faults[].step"), or nullptr.
const KeySpec* FindKey(std::string_view key);
// Where a key sits in a document: {"agents", "count"}, {"faults"}. A key's name may itself
// be dotted ("security.enabled"): a mapping nested in its section, {"network", "security",
// "enabled"}.
std::vector<std::string> KeyPath(const KeySpec& spec);

// Keys by their name within a section; a dotted name ("security.enabled") sits in a mapping
// nested in it.
using NamedKeys = std::vector<std::pair<std::string, const KeySpec*>>;
// Walks `keys` in order as a document nests them: leaf(name, spec) for an undotted name;
// group(head, nested) once per nested mapping, at its first key, with its keys renamed
// relative to it. The YAML output and the reference share it.
void VisitNested(const NamedKeys& keys,
                 const std::function<void(const std::string&, const KeySpec&)>& leaf,
                 const std::function<void(const std::string&, const NamedKeys&)>& group);

// Calls visit(spec, yaml) for every key of Schema(), in order, with the key's effective
// value in `config` as YAML text on one line (flow style for points, lists and records;
// a string double-quoted). Executables build other formats (JSON) with it.
void VisitConfig(const Config& config,
                 const std::function<void(const KeySpec& spec, const std::string& yaml)>& visit);

}  // namespace deif
