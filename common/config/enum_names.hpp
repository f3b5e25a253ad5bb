// The names the configuration gives the enums of the core and of the config: one table per
// enum, and ToString / FromString over it. The YAML reader, the YAML and JSON output and
// the generated reference (docs/CONFIG.md) all use these tables.
#pragma once

#include <string>
#include <string_view>
#include <vector>

#include "common/core/control_law.hpp"
#include "common/core/models.hpp"

namespace deif {

// Declared here, defined in common/config/config.hpp.
enum class StepMode;
enum class FaultAction;
enum class DiscoveryKind;
enum class TransportKind;
enum class ExchangeKind;
enum class MembershipKind;

template <typename Enum>
struct EnumName {
  const char* name;
  Enum value;
};

// The table of an enum, in the order the documentation lists the names.
template <typename Enum>
const std::vector<EnumName<Enum>>& EnumTable();
template <>
const std::vector<EnumName<ControlLawKind>>& EnumTable<ControlLawKind>();
template <>
const std::vector<EnumName<MotionModelKind>>& EnumTable<MotionModelKind>();
template <>
const std::vector<EnumName<TrajectoryKind>>& EnumTable<TrajectoryKind>();
template <>
const std::vector<EnumName<StepMode>>& EnumTable<StepMode>();
template <>
const std::vector<EnumName<FaultAction>>& EnumTable<FaultAction>();
template <>
const std::vector<EnumName<DiscoveryKind>>& EnumTable<DiscoveryKind>();
template <>
const std::vector<EnumName<TransportKind>>& EnumTable<TransportKind>();
template <>
const std::vector<EnumName<ExchangeKind>>& EnumTable<ExchangeKind>();
template <>
const std::vector<EnumName<MembershipKind>>& EnumTable<MembershipKind>();

// The name of a value ("?" for a value outside the table).
const char* ToString(ControlLawKind law);
const char* ToString(MotionModelKind kind);
const char* ToString(TrajectoryKind kind);
const char* ToString(StepMode mode);
const char* ToString(FaultAction action);
const char* ToString(DiscoveryKind kind);
const char* ToString(TransportKind kind);
const char* ToString(ExchangeKind kind);
const char* ToString(MembershipKind kind);

// The value of a name; false (and *value unchanged) for a name outside the table.
template <typename Enum>
bool FromString(std::string_view name, Enum* value) {
  for (const EnumName<Enum>& entry : EnumTable<Enum>()) {
    if (name == entry.name) {
      *value = entry.value;
      return true;
    }
  }
  return false;
}

// Every name of an enum, in table order.
template <typename Enum>
std::vector<std::string> EnumNames() {
  std::vector<std::string> names;
  for (const EnumName<Enum>& entry : EnumTable<Enum>()) names.emplace_back(entry.name);
  return names;
}

}  // namespace deif
