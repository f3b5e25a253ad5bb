// Inside the config library: how a schema key reads and writes its field of the Config (or
// of one element of a record list), and how its value is written as YAML.
#pragma once

#include <cstdint>
#include <functional>
#include <optional>
#include <string>
#include <variant>
#include <vector>

#include "common/config/schema.hpp"
#include "common/core/types.hpp"

namespace YAML {
class Emitter;
}

namespace deif {

// A key's value, whatever its type. Enums hold their name, integer lists int64.
using SchemaValue = std::variant<double, std::int64_t, std::uint64_t, bool, std::string,
                                 Vector2, std::vector<double>, std::vector<std::int64_t>>;

struct KeyAccess {
  // `record` is the Config for a top-level key, the element for a record field.
  // get gives nullopt for a field an element does not have (faults[].agent of a
  // restart_target).
  std::function<std::optional<SchemaValue>(const void* record)> get;
  std::function<void(void* record, const SchemaValue& value)> set;
  std::optional<SchemaValue> default_value;
  // A rule of the key alone beyond its range: the reason a value is refused, or "".
  std::function<std::string(const SchemaValue& value)> check;
  // kRecordList: the number of elements, the i-th one, a new element appended with its
  // struct defaults, and removing them all.
  std::function<std::size_t(const void* record)> size;
  std::function<const void*(const void* record, std::size_t i)> element;
  std::function<void*(void* record)> append;
  std::function<void(void* record)> clear;
};

// The shortest decimal text that reads back to the same double (.inf, -.inf, .nan).
std::string FormatNumber(double value);

// Writes the value of `spec` in `record` to the emitter (lists and records in flow style
// when `flow`, else records as a block list of flow mappings).
void EmitKeyValue(YAML::Emitter& out, const KeySpec& spec, const void* record, bool flow);
// The same as one line of flow YAML.
std::string KeyValueYaml(const KeySpec& spec, const void* record);
// A value as one line of flow YAML (not for kRecordList).
std::string ValueYaml(const KeySpec& spec, const SchemaValue& value);

}  // namespace deif
