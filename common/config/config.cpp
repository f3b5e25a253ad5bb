// YAML -> Config through the schema (schema.cpp), the rules between keys, the command-line
// overrides, and Config -> YAML.
//
// Every error is a ConfigError naming the file, the dotted key and the line, so that the
// executables can print one clear line and stop before starting anything.
#include "common/config/config.hpp"

#include <yaml-cpp/yaml.h>

#include <algorithm>
#include <cctype>
#include <cerrno>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <initializer_list>
#include <limits>
#include <map>
#include <set>
#include <utility>

#include "common/config/document.hpp"
#include "common/config/schema.hpp"
#include "common/config/schema_access.hpp"

namespace deif {

namespace {

using Kind = DocNode::Kind;

constexpr const char* kOverridePrefix = "--set ";

std::string BuildMessage(const std::string& file, const std::string& key, int line,
                         const std::string& reason) {
  std::string message = file.empty() ? std::string("<config>") : file;
  if (line > 0) message += ":" + std::to_string(line);
  message += ": ";
  if (!key.empty()) message += "key '" + key + "': ";
  message += reason;
  // One line, whatever the file name, an override or a quoted value held: control
  // characters are shown escaped (docs/RUNNING.md: one line on stderr).
  std::string line_only;
  for (const char ch : message) {
    const auto byte = static_cast<unsigned char>(ch);
    if (ch == '\n') {
      line_only += "\\n";
    } else if (byte < 0x20 || byte == 0x7F) {
      char escaped[8];
      std::snprintf(escaped, sizeof escaped, "\\x%02X", static_cast<unsigned>(byte));
      line_only += escaped;
    } else {
      line_only += ch;
    }
  }
  return line_only;
}

[[noreturn]] void Fail(const DocNode& node, const std::string& key, const std::string& reason) {
  throw ConfigError(node.SourceName(), key, node.line, reason);
}

std::string Join(const std::vector<std::string>& names) {
  std::string out;
  for (const std::string& name : names) out += (out.empty() ? "" : ", ") + name;
  return out;
}

std::string Where(const DocNode& node) {
  return node.SourceName() + (node.line > 0 ? ":" + std::to_string(node.line) : "");
}

// ---------------------------------------------------------------------------------------
// Scalars. The text of a number is checked by hand: YAML numbers are decimal, and strtod
// alone would also take "inf", "nan", hex floats and leading blanks.

const std::string& PlainText(const DocNode& node, const std::string& key,
                             const std::string& expected) {
  if (node.kind != Kind::kScalar || node.quoted) {
    Fail(node, key, "expected " + expected + " (got " + node.Describe() + ")");
  }
  return node.text;
}

std::string Expected(const KeySpec& spec, const char* otherwise) {
  return spec.expected.empty() ? otherwise : spec.expected;
}

double ReadDouble(const KeySpec& spec, const DocNode& node, const std::string& key) {
  const std::string& text = PlainText(node, key, Expected(spec, "a number"));
  static const std::set<std::string> kInf = {".inf", ".Inf", ".INF", "+.inf", "+.Inf", "+.INF"};
  static const std::set<std::string> kMinusInf = {"-.inf", "-.Inf", "-.INF"};
  static const std::set<std::string> kNan = {".nan", ".NaN", ".NAN"};
  double value = 0.0;
  if (kInf.count(text) != 0) {
    value = std::numeric_limits<double>::infinity();
  } else if (kMinusInf.count(text) != 0) {
    value = -std::numeric_limits<double>::infinity();
  } else if (kNan.count(text) != 0) {
    value = std::numeric_limits<double>::quiet_NaN();
  } else {
    const bool decimal =
        !text.empty() && text.find_first_not_of("0123456789+-.eE") == std::string::npos &&
        text.find_first_of("0123456789") != std::string::npos;
    char* end = nullptr;
    errno = 0;
    value = decimal ? std::strtod(text.c_str(), &end) : 0.0;
    if (!decimal || end != text.c_str() + text.size()) {
      Fail(node, key, "expected " + Expected(spec, "a number") + " (got " + node.Describe() + ")");
    }
    if (errno == ERANGE) Fail(node, key, "number out of range (got " + text + ")");
  }
  if (std::isnan(value) || (std::isinf(value) && !(spec.allow_infinity && value > 0))) {
    Fail(node, key,
         std::string("must be a finite number") + (spec.allow_infinity ? " or .inf" : "") +
             " (got " + text + ")");
  }
  return value;
}

// Decimal digits, optionally signed, without leading zeros (YAML 1.1 reads 010 as 8).
std::int64_t ReadInt(const KeySpec& spec, const DocNode& node, const std::string& key) {
  const std::string expected = Expected(spec, "an integer");
  const std::string& text = PlainText(node, key, expected);
  const std::size_t sign = !text.empty() && (text[0] == '-' || text[0] == '+') ? 1 : 0;
  const bool digits = text.size() > sign &&
                      text.find_first_not_of("0123456789", sign) == std::string::npos;
  if (!digits) Fail(node, key, "expected " + expected + " (got " + node.Describe() + ")");
  if (text[sign] == '0' && text.size() > sign + 1) {
    Fail(node, key, "an integer is written without leading zeros (got " + text + ")");
  }
  errno = 0;
  const long long value = std::strtoll(text.c_str(), nullptr, 10);
  if (errno == ERANGE) Fail(node, key, "integer out of range (got " + text + ")");
  return static_cast<std::int64_t>(value);
}

std::uint64_t ReadUint(const KeySpec& spec, const DocNode& node, const std::string& key) {
  const std::string expected = Expected(spec, "a non-negative integer below 2^64");
  const std::string& text = PlainText(node, key, expected);
  const bool digits = !text.empty() && text.find_first_not_of("0123456789") == std::string::npos &&
                      (text[0] != '0' || text.size() == 1);
  errno = 0;
  const unsigned long long value = digits ? std::strtoull(text.c_str(), nullptr, 10) : 0;
  if (!digits || errno == ERANGE) {
    Fail(node, key, "expected " + expected + " (got " + node.Describe() + ")");
  }
  return static_cast<std::uint64_t>(value);
}

bool ReadBool(const DocNode& node, const std::string& key) {
  const std::string& text = PlainText(node, key, "true or false");
  if (text == "true" || text == "True" || text == "TRUE") return true;
  if (text == "false" || text == "False" || text == "FALSE") return false;
  Fail(node, key, "expected true or false (got " + node.Describe() + ")");
}

// The code points of valid UTF-8, or false.
bool DecodeUtf8(const std::string& text, std::vector<std::uint32_t>* out) {
  for (std::size_t i = 0; i < text.size();) {
    const auto byte = static_cast<unsigned char>(text[i]);
    std::size_t extra = 0;
    std::uint32_t code = byte;
    if (byte >= 0xF5 || (byte >= 0x80 && byte < 0xC2)) return false;
    if (byte >= 0xF0) {
      extra = 3, code = byte & 0x07u;
    } else if (byte >= 0xE0) {
      extra = 2, code = byte & 0x0Fu;
    } else if (byte >= 0xC2) {
      extra = 1, code = byte & 0x1Fu;
    }
    if (i + extra >= text.size()) return false;
    for (std::size_t k = 1; k <= extra; ++k) {
      const auto next = static_cast<unsigned char>(text[i + k]);
      if ((next & 0xC0u) != 0x80u) return false;
      code = (code << 6) | (next & 0x3Fu);
    }
    static const std::uint32_t kMin[] = {0, 0x80, 0x800, 0x10000};
    if (code < kMin[extra] || code > 0x10FFFF || (code >= 0xD800 && code <= 0xDFFF)) {
      return false;
    }
    out->push_back(code);
    i += extra + 1;
  }
  return true;
}

std::string ReadString(const KeySpec& spec, const DocNode& node, const std::string& key) {
  if (node.kind != Kind::kScalar) {
    Fail(node, key, "expected " + Expected(spec, "a string") + " (got " + node.Describe() + ")");
  }
  std::vector<std::uint32_t> codes;
  if (!DecodeUtf8(node.text, &codes)) Fail(node, key, "must be valid UTF-8");
  for (std::size_t i = 0; i < codes.size(); ++i) {
    const std::uint32_t c = codes[i];
    if (c < 0x20 || c == 0x7F || (c >= 0x80 && c <= 0x9F)) {
      char hex[8];
      std::snprintf(hex, sizeof(hex), "%04X", static_cast<unsigned>(c));
      Fail(node, key,
           std::string("must be printable (control character U+") + hex + " at character " +
               std::to_string(i + 1) + ")");
    }
  }
  if (spec.max_length > 0 && (codes.size() < spec.min_length || codes.size() > spec.max_length)) {
    Fail(node, key,
         "must be " + std::to_string(spec.min_length) + ".." + std::to_string(spec.max_length) +
             " characters long (got " + std::to_string(codes.size()) + ")");
  }
  return node.text;
}

std::string ReadEnum(const KeySpec& spec, const DocNode& node, const std::string& key) {
  if (node.kind != Kind::kScalar) {
    Fail(node, key, "expected one of " + Join(spec.enum_names) + " (got " + node.Describe() + ")");
  }
  if (std::find(spec.enum_names.begin(), spec.enum_names.end(), node.text) ==
      spec.enum_names.end()) {
    Fail(node, key, "unknown value '" + node.text + "'; allowed: " + Join(spec.enum_names));
  }
  return node.text;
}

// The rule a number breaks, as "must be ..." says it: "in 2..512", "> 0 and <= 86400".
std::string RangeRule(const KeySpec& spec) {
  const bool integral = spec.type == KeyType::kInt || spec.type == KeyType::kInt64 ||
                        spec.type == KeyType::kIntList;
  if (integral && spec.min && spec.max && spec.min->inclusive && spec.max->inclusive) {
    return "in " + FormatNumber(spec.min->value) + ".." + FormatNumber(spec.max->value);
  }
  std::string rule;
  if (spec.min) {
    rule = std::string(spec.min->inclusive ? ">= " : "> ") + FormatNumber(spec.min->value);
  }
  if (spec.max) {
    rule += std::string(rule.empty() ? "" : " and ") + (spec.max->inclusive ? "<= " : "< ") +
            FormatNumber(spec.max->value);
  }
  if (spec.allow_infinity) rule += ", or .inf";
  return rule;
}

void CheckRange(const KeySpec& spec, double value, const DocNode& node, const std::string& key) {
  if (std::isinf(value) && spec.allow_infinity) return;
  const bool low = spec.min && (spec.min->inclusive ? value < spec.min->value
                                                    : value <= spec.min->value);
  const bool high = spec.max && (spec.max->inclusive ? value > spec.max->value
                                                     : value >= spec.max->value);
  if (low || high) Fail(node, key, "must be " + RangeRule(spec) + " (got " + node.text + ")");
}

double ReadNumberInRange(const KeySpec& spec, const DocNode& node, const std::string& key) {
  const double value = ReadDouble(spec, node, key);
  CheckRange(spec, value, node, key);
  return value;
}

std::int64_t ReadIntInRange(const KeySpec& spec, const DocNode& node, const std::string& key) {
  const std::int64_t value = ReadInt(spec, node, key);
  CheckRange(spec, static_cast<double>(value), node, key);
  // An int field without a range of its own (an agent id, checked against agents.count).
  if ((spec.type == KeyType::kInt || spec.type == KeyType::kIntList) &&
      (value < std::numeric_limits<int>::min() || value > std::numeric_limits<int>::max())) {
    Fail(node, key, "integer out of range (got " + node.text + ")");
  }
  return value;
}

// Where each key of the document is (with list elements: "faults[0].step",
// "agents.initial_angles_rad[2]"), for the rules between keys.
using Locations = std::map<std::string, const DocNode*>;

const DocNode& RequireList(const DocNode& node, const std::string& key, const char* expected) {
  if (node.kind != Kind::kSequence) {
    Fail(node, key, std::string("expected ") + expected + " (got " + node.Describe() + ")");
  }
  return node;
}

SchemaValue ReadValue(const KeySpec& spec, const DocNode& node, const std::string& key,
                      Locations* at) {
  at->emplace(key, &node);
  const auto item_key = [&](std::size_t i) { return key + "[" + std::to_string(i) + "]"; };
  SchemaValue value;
  switch (spec.type) {
    case KeyType::kDouble:
      value = ReadNumberInRange(spec, node, key);
      break;
    case KeyType::kInt:
    case KeyType::kInt64:
      value = ReadIntInRange(spec, node, key);
      break;
    case KeyType::kUint64:
      value = ReadUint(spec, node, key);
      break;
    case KeyType::kBool:
      value = ReadBool(node, key);
      break;
    case KeyType::kString:
      value = ReadString(spec, node, key);
      break;
    case KeyType::kEnum:
      value = ReadEnum(spec, node, key);
      break;
    case KeyType::kVector2: {
      if (node.kind != Kind::kSequence || node.items.size() != 2) {
        Fail(node, key,
             "expected a list of two numbers [x, y] (got " +
                 (node.kind == Kind::kSequence
                      ? "a list of " + std::to_string(node.items.size())
                      : node.Describe()) +
                 ")");
      }
      value = Vector2(ReadNumberInRange(spec, node.items[0], item_key(0)),
                      ReadNumberInRange(spec, node.items[1], item_key(1)));
      break;
    }
    case KeyType::kDoubleList: {
      std::vector<double> values;
      for (const DocNode& item : RequireList(node, key, "a list of numbers").items) {
        at->emplace(item_key(values.size()), &item);
        values.push_back(ReadNumberInRange(spec, item, item_key(values.size())));
      }
      value = std::move(values);
      break;
    }
    case KeyType::kIntList: {
      std::vector<std::int64_t> values;
      for (const DocNode& item : RequireList(node, key, "a list of integers").items) {
        at->emplace(item_key(values.size()), &item);
        values.push_back(ReadIntInRange(spec, item, item_key(values.size())));
      }
      value = std::move(values);
      break;
    }
    case KeyType::kRecordList:
      break;  // ReadRecords
  }
  if (spec.access->check) {
    const std::string reason = spec.access->check(value);
    if (!reason.empty()) Fail(node, key, reason + " (got " + node.text + ")");
  }
  return value;
}

std::vector<std::string> Names(const std::vector<KeySpec>& keys) {
  std::vector<std::string> names;
  for (const KeySpec& key : keys) names.push_back(key.name);
  return names;
}

std::vector<std::string> Names(const std::vector<const KeySpec*>& keys) {
  std::vector<std::string> names;
  for (const KeySpec* key : keys) names.push_back(key->name);
  return names;
}

// A mapping whose keys must all be in `allowed`; null stands for an empty one.
void CheckMapping(const DocNode& node, const std::string& path,
                  const std::vector<std::string>& allowed, const std::string& expected) {
  if (node.IsNull()) return;
  if (!node.IsMap()) Fail(node, path, "expected " + expected + " (got " + node.Describe() + ")");
  for (const DocEntry& entry : node.entries) {
    if (std::find(allowed.begin(), allowed.end(), entry.key) == allowed.end()) {
      throw ConfigError(entry.value.SourceName(), path.empty() ? entry.key : path + "." + entry.key,
                        entry.key_line, "unknown key; allowed: " + Join(allowed));
    }
  }
}

void ApplyDefaults(const std::vector<KeySpec>& keys, void* record) {
  for (const KeySpec& spec : keys) {
    if (spec.type == KeyType::kRecordList) {
      spec.access->clear(record);
    } else if (spec.access->default_value) {
      spec.access->set(record, *spec.access->default_value);
    }
  }
}

std::string WithArticle(const std::string& noun) {
  return (std::string("aeiou").find(noun[0]) != std::string::npos ? "an " : "a ") + noun;
}

void ReadRecords(const KeySpec& spec, const DocNode& node, const std::string& key, void* record,
                 Locations* at) {
  at->emplace(key, &node);
  spec.access->clear(record);
  if (node.IsNull()) return;
  const std::string shape = "{" + Join(Names(spec.fields)) + "}";
  if (node.kind != Kind::kSequence) {
    Fail(node, key, "expected a list of " + shape + " (got " + node.Describe() + ")");
  }
  for (std::size_t i = 0; i < node.items.size(); ++i) {
    const DocNode& item = node.items[i];
    const std::string path = key + "[" + std::to_string(i) + "]";
    at->emplace(path, &item);
    if (!item.IsMap()) {
      Fail(item, path, "expected a mapping " + shape + " (got " + item.Describe() + ")");
    }
    CheckMapping(item, path, Names(spec.fields), "a mapping " + shape);
    void* element = spec.access->append(record);
    ApplyDefaults(spec.fields, element);
    for (const KeySpec& field : spec.fields) {
      const DocNode* value = item.Find(field.name);
      const std::string field_key = path + "." + field.name;
      if (value == nullptr) {
        if (field.required) {
          Fail(item, field_key,
               "missing (every " + spec.element_noun + " needs " + WithArticle(field.name) + ")");
        }
        continue;
      }
      field.access->set(element, ReadValue(field, *value, field_key, at));
    }
  }
}

// ---------------------------------------------------------------------------------------
// The rules between keys, after every key is read.

class Rules {
 public:
  Rules(const Config& config, const Locations& at, const std::string& source)
      : c_(config), at_(at), source_(source) {}

  void Check() {
    Sensing();
    Agents();
    Network();
    NetworkSim();
    Faults();
  }

 private:
  const DocNode* At(const std::string& key) const {
    const auto it = at_.find(key);
    return it == at_.end() ? nullptr : it->second;
  }
  bool FromOverride(const DocNode* node) const {
    return node != nullptr && node->SourceName().rfind(kOverridePrefix, 0) == 0;
  }

  // Fails at the first of `keys` set with --set, else at the first present, else (all
  // defaults) at the first without a line.
  [[noreturn]] void Blame(std::initializer_list<std::string> keys,
                          const std::string& reason) const {
    for (const std::string& key : keys) {
      if (FromOverride(At(key))) Fail(*At(key), key, reason);
    }
    for (const std::string& key : keys) {
      if (At(key) != nullptr) Fail(*At(key), key, reason);
    }
    throw ConfigError(source_, *keys.begin(), 0, reason);
  }

  // A value beyond a limit set by another key: blames the limit when only the limit came
  // from --set (the file was fine until the command line changed the limit).
  [[noreturn]] void BeyondLimit(const std::string& key, const std::string& limit_key,
                                const std::string& reason, const std::string& limit_reason) const {
    const DocNode* node = At(key);
    const DocNode* limit = At(limit_key);
    if (FromOverride(limit) && !FromOverride(node) && node != nullptr) {
      Fail(*limit, limit_key, limit_reason + " (" + key + " at " + Where(*node) + ")");
    }
    Blame({key}, reason);
  }

  void Sensing() const {
    const SensingFunction& s = c_.sensing;
    if (!(s.r1_m > s.r0_m)) {
      Blame({"sensing.r1_m", "sensing.r0_m"}, "r1_m must be > r0_m (got r0_m " +
                                                   FormatNumber(s.r0_m) + ", r1_m " +
                                                   FormatNumber(s.r1_m) + ")");
    }
  }

  void Agents() const {
    const auto& angles = c_.agents.initial_angles_rad;
    if (!angles.empty() && static_cast<int>(angles.size()) != c_.agents.count) {
      Blame({"agents.initial_angles_rad", "agents.count"},
            "must have one angle per agent: length must equal agents.count = " +
                std::to_string(c_.agents.count) + " (got " + std::to_string(angles.size()) + ")");
    }
  }

  void Network() const {
    const NetworkConfig& n = c_.network;
    if (!(n.participant_announcement_s < n.participant_lease_s)) {
      Blame({"network.participant_announcement_s", "network.participant_lease_s"},
            "participant_announcement_s must be < participant_lease_s (got " +
                FormatNumber(n.participant_announcement_s) + " >= " +
                FormatNumber(n.participant_lease_s) + ")");
    }
    if (n.security.enabled && n.security.dir.empty()) {
      Blame({"network.security.dir", "network.security.enabled"},
            "security.enabled needs the folder of the certificates (scripts/deif-certs)");
    }
    if (n.security.enabled && n.ros2_naming) {
      // Each process's role is its publisher's partition (docs/SECURITY.md); ROS 2 naming
      // publishes in the default partition.
      Blame({"network.security.enabled", "network.ros2_naming"},
            "security.enabled needs ros2_naming: false");
    }
    if (n.exchange == ExchangeKind::kTree && n.security.enabled) {
      // DDS Security authenticates the relay, not the origin of what it forwards, and the
      // permissions grant no relay partitions (docs/SCALING.md, "Trust").
      Blame({"network.exchange", "network.security.enabled"},
            "exchange: tree needs security.enabled: false (a relay's forwarded contributions "
            "cannot be authenticated)");
    }
    if (n.membership == MembershipKind::kRollCall && EffectiveExchange(c_) != ExchangeKind::kTree) {
      // Over all to all every contribution travels on deif/contribution, whose readers are
      // what this membership does without.
      Blame({"network.membership", "network.exchange"},
            std::string("membership: roll_call needs the tree exchange (exchange: tree, or auto from ") +
                std::to_string(kTreeFromAgents) + " agents on in plain runs); this run's is all_to_all");
    }
    if (n.exchange == ExchangeKind::kTree && n.ros2_naming) {
      Blame({"network.exchange", "network.ros2_naming"},
            "exchange: tree needs ros2_naming: false (its relays use partitions)");
    }
    if (n.security.enabled && n.discovery == DiscoveryKind::kServer) {
      // Fast DDS 2.9.1 authenticates no participant through a Discovery Server (secure
      // Discovery Server came with Fast DDS 2.10): every secure process stalled at start,
      // the run never began (docs/SECURITY.md, "Known limits").
      Blame({"network.discovery", "network.security.enabled"},
            "security.enabled needs discovery: simple (Fast DDS 2.9.1 cannot authenticate "
            "through a Discovery Server)");
    }
  }

  void StepWithinRun(const std::string& key, StepIndex step) const {
    if (step > c_.scenario.steps) {
      const std::string steps = std::to_string(c_.scenario.steps);
      BeyondLimit(key, "scenario.steps",
                  "must be in 1..scenario.steps = 1.." + steps + " (got " +
                      std::to_string(step) + ")",
                  "a step " + std::to_string(step) + " lies beyond scenario.steps = " + steps);
    }
  }

  void AgentWithinCount(const std::string& key, AgentId id) const {
    if (id < 1) Blame({key}, "agent id must be in 1.." + std::to_string(c_.agents.count) +
                                 " (got " + std::to_string(id) + ")");
    if (id > c_.agents.count) {
      const std::string count = std::to_string(c_.agents.count);
      BeyondLimit(key, "agents.count",
                  "agent id must be in 1.." + count + " (got " + std::to_string(id) + ")",
                  "agent " + std::to_string(id) + " does not exist with agents.count = " + count);
    }
  }

  void NetworkSim() const {
    const NetworkSimConfig& n = c_.network_sim;
    if (n.delay_min_s > n.delay_max_s) {
      Blame({"network_sim.delay_max_s", "network_sim.delay_min_s"},
            "delay_min_s must be <= delay_max_s (got " + FormatNumber(n.delay_min_s) + " > " +
                FormatNumber(n.delay_max_s) + ")");
    }
    for (std::size_t i = 0; i < n.partitions.size(); ++i) {
      const PartitionConfig& p = n.partitions[i];
      const std::string path = "network_sim.partitions[" + std::to_string(i) + "]";
      StepWithinRun(path + ".from_step", p.from_step);
      StepWithinRun(path + ".to_step", p.to_step);
      if (p.to_step < p.from_step) {
        Blame({path + ".to_step"}, "must be >= from_step = " + std::to_string(p.from_step) +
                                       " (got " + std::to_string(p.to_step) + ")");
      }
      std::set<AgentId> seen;
      for (std::size_t j = 0; j < p.group.size(); ++j) {
        const std::string key = path + ".group[" + std::to_string(j) + "]";
        AgentWithinCount(key, p.group[j]);
        if (!seen.insert(p.group[j]).second) {
          Blame({key}, "agent " + std::to_string(p.group[j]) + " appears twice in the group");
        }
      }
      if (p.group.empty() && !p.with_target) {
        Blame({path + ".group", path},
              "must name at least one agent (or set with_target: true to cut off the target)");
      }
    }
  }

  // Faults are checked as a sequence in step order: nothing happens to a killed agent, cont
  // only follows stop, and one agent at least survives.
  void Faults() const {
    const std::vector<FaultConfig>& faults = c_.faults;
    for (std::size_t i = 0; i < faults.size(); ++i) {
      const FaultConfig& f = faults[i];
      const std::string path = "faults[" + std::to_string(i) + "]";
      StepWithinRun(path + ".step", f.step);
      const bool has_agent = At(path + ".agent") != nullptr;
      if (f.action == FaultAction::kRestartTarget) {
        if (has_agent) Blame({path + ".agent"}, "restart_target takes no agent");
      } else if (!has_agent) {
        Fail(*At(path), path + ".agent",
             std::string("missing (action ") + ToString(f.action) + " needs an agent id)");
      } else {
        AgentWithinCount(path + ".agent", f.agent_id);
      }
    }
    std::vector<std::size_t> order(faults.size());
    for (std::size_t i = 0; i < order.size(); ++i) order[i] = i;
    std::stable_sort(order.begin(), order.end(), [&](std::size_t a, std::size_t b) {
      return faults[a].step < faults[b].step;
    });
    enum class State { kRunning, kStopped, kKilled };
    std::map<AgentId, State> state;
    int killed = 0;
    for (const std::size_t i : order) {
      const FaultConfig& f = faults[i];
      if (f.action == FaultAction::kRestartTarget) continue;
      const std::string key = "faults[" + std::to_string(i) + "].action";
      State& st = state[f.agent_id];
      const std::string who = "agent " + std::to_string(f.agent_id);
      if (st == State::kKilled) {
        Blame({key}, who + " was already killed before step " + std::to_string(f.step));
      }
      switch (f.action) {
        case FaultAction::kKill:
          st = State::kKilled;
          ++killed;
          break;
        case FaultAction::kStop:
          if (st == State::kStopped) Blame({key}, who + " is already stopped");
          st = State::kStopped;
          break;
        case FaultAction::kCont:
          if (st != State::kStopped) Blame({key}, "cont needs an earlier stop of " + who);
          st = State::kRunning;
          break;
        case FaultAction::kRestartTarget:
          break;
      }
    }
    if (killed >= c_.agents.count) {
      Blame({"faults", "agents.count"}, "the faults kill every agent; at least one must survive");
    }
  }

  const Config& c_;
  const Locations& at_;
  const std::string& source_;
};

// ---------------------------------------------------------------------------------------

std::string TopLevelNames() {
  std::vector<std::string> names;
  for (const SectionSpec& section : Sections()) names.push_back(section.name);
  return Join(names);
}

void CheckTopLevel(const DocNode& root) {
  if (!root.IsNull() && !root.IsMap()) {
    Fail(root, "", "the top level must be a mapping of sections (" + TopLevelNames() + "; got " +
                       root.Describe() + ")");
  }
}

// A section's mapping, or a mapping nested in it (network.security): its keys must be the
// first components of `names`, the key names below it (dotted ones name nested mappings).
void CheckKeys(const DocNode& node, const std::string& path, const std::vector<std::string>& names) {
  std::vector<std::string> heads;
  std::map<std::string, std::vector<std::string>> nested;
  for (const std::string& name : names) {
    const std::size_t dot = name.find('.');
    const std::string head = name.substr(0, dot);
    if (std::find(heads.begin(), heads.end(), head) == heads.end()) heads.push_back(head);
    if (dot != std::string::npos) nested[head].push_back(name.substr(dot + 1));
  }
  CheckMapping(node, path, heads, "a mapping of keys");
  for (const auto& [head, rest] : nested) {
    const DocNode* child = node.IsMap() ? node.Find(head) : nullptr;
    if (child != nullptr) CheckKeys(*child, path + "." + head, rest);
  }
}

const DocNode* FindKeyNode(const DocNode& root, const KeySpec& spec) {
  const DocNode* node = &root;
  for (const std::string& part : KeyPath(spec)) {
    node = node->Find(part);
    if (node == nullptr) return nullptr;
  }
  return node;
}

Config ParseTree(const DocNode& root, const std::string& source_name) {
  CheckTopLevel(root);
  std::vector<std::string> top;
  for (const SectionSpec& section : Sections()) top.push_back(section.name);
  CheckMapping(root, "", top, "a mapping");
  for (const SectionSpec& section : Sections()) {
    const DocNode* node = root.Find(section.name);
    if (node != nullptr && !section.is_key) CheckKeys(*node, section.name, Names(section.keys));
  }

  Config config;
  config.source = source_name;
  ApplyDefaults(Schema(), &config);
  Locations at;
  for (const KeySpec& spec : Schema()) {
    const DocNode* node = FindKeyNode(root, spec);
    if (node == nullptr) continue;
    if (spec.type == KeyType::kRecordList) {
      ReadRecords(spec, *node, spec.key, &config, &at);
    } else {
      spec.access->set(&config, ReadValue(spec, *node, spec.key, &at));
    }
  }
  config.filter.motion_model.dt_s = config.scenario.dt_s;
  Rules(config, at, source_name).Check();
  return config;
}

// ---------------------------------------------------------------------------------------
// Overrides.

struct Override {
  std::string key;    // dotted
  std::string value;  // YAML text
};

Override SplitOverride(const std::string& text) {
  const std::size_t eq = text.find('=');
  if (eq == std::string::npos || eq == 0) {
    throw ConfigError(kOverridePrefix + text, "", 0,
                      "expected dotted.key=value with a YAML value, e.g. agents.count=6");
  }
  Override o{text.substr(0, eq), text.substr(eq + 1)};
  bool good = o.key.front() != '.' && o.key.back() != '.' &&
              o.key.find("..") == std::string::npos;
  for (const char ch : o.key) {
    good = good && (std::isalnum(static_cast<unsigned char>(ch)) != 0 || ch == '_' || ch == '.');
  }
  if (!good) {
    throw ConfigError(kOverridePrefix + o.key, "", 0,
                      "not a dotted key (names of letters, digits and _ joined by '.')");
  }
  return o;
}

void ClearLines(DocNode* node) {
  node->line = 0;
  for (DocNode& item : node->items) ClearLines(&item);
  for (DocEntry& entry : node->entries) {
    entry.key_line = 0;
    ClearLines(&entry.value);
  }
}

void ApplyOverride(DocNode* root, const Override& o) {
  const std::string source = kOverridePrefix + o.key;
  const bool one_line = o.value.find('\n') == std::string::npos;  // then no line to name
  DocNode value;
  try {
    value = ReadDocument(o.value, source);
  } catch (const ConfigError& e) {
    if (!one_line) throw;
    throw ConfigError(e.file(), e.key(), 0, e.reason());
  }
  if (one_line) ClearLines(&value);
  const auto made_here = std::make_shared<const std::string>(source);

  std::vector<std::string> parts;
  for (std::size_t start = 0;;) {
    const std::size_t dot = o.key.find('.', start);
    parts.push_back(o.key.substr(start, dot - start));
    if (dot == std::string::npos) break;
    start = dot + 1;
  }
  DocNode* node = root;
  std::string path;
  for (std::size_t i = 0; i < parts.size(); ++i) {
    if (node->IsNull()) {
      node->kind = Kind::kMap;
      node->source = made_here;
      node->line = 0;
    }
    if (!node->IsMap()) {
      throw ConfigError(source, o.key, 0,
                        "cannot set it: " + path + " (" + Where(*node) + ") is " +
                            node->Describe() + ", not a mapping");
    }
    path += (path.empty() ? "" : ".") + parts[i];
    DocNode* child = node->Find(parts[i]);
    if (child == nullptr) {
      DocEntry entry;
      entry.key = parts[i];
      entry.value.source = made_here;
      node->entries.push_back(std::move(entry));
      child = &node->entries.back().value;
    }
    if (i + 1 == parts.size()) {
      for (DocEntry& entry : node->entries) {
        if (&entry.value == child) entry.key_line = 0;  // the key is the override's now
      }
      *child = std::move(value);
      return;
    }
    node = child;
  }
}

// agents.count changed on the command line without new angles: a file's angle list of
// another length would be refused, so the agents start evenly spaced instead.
void DropStaleAngles(DocNode* root, const std::vector<Override>& overrides) {
  bool count_set = false;
  for (const Override& o : overrides) {
    if (o.key == "agents.count") count_set = true;
    if (o.key == "agents.initial_angles_rad" || o.key == "agents") return;
  }
  DocNode* agents = count_set ? root->Find("agents") : nullptr;
  if (agents == nullptr || !agents->IsMap()) return;
  const DocNode* count = agents->Find("count");
  const DocNode* angles = agents->Find("initial_angles_rad");
  if (count == nullptr || angles == nullptr || angles->kind != Kind::kSequence ||
      count->kind != Kind::kScalar || count->quoted ||
      count->text.find_first_not_of("0123456789") != std::string::npos || count->text.empty() ||
      count->text.size() > 6) {
    return;
  }
  if (angles->items.size() == static_cast<std::size_t>(std::stoi(count->text))) return;
  auto& entries = agents->entries;
  entries.erase(std::remove_if(entries.begin(), entries.end(),
                               [](const DocEntry& e) { return e.key == "initial_angles_rad"; }),
                entries.end());
}

// The keys of a section (or of a mapping nested in it) as a mapping, in schema order; a
// dotted name ("security.enabled") opens a nested mapping.
void EmitKeys(YAML::Emitter& out, const NamedKeys& keys,
              const Config& config) {
  out << YAML::BeginMap;
  VisitNested(
      keys,
      [&](const std::string& name, const KeySpec& spec) {
        out << YAML::Key << name << YAML::Value;
        EmitKeyValue(out, spec, &config, /*flow=*/false);
      },
      [&](const std::string& head, const NamedKeys& nested) {
        out << YAML::Key << head << YAML::Value;
        EmitKeys(out, nested, config);
      });
  out << YAML::EndMap;
}

}  // namespace

// ---------------------------------------------------------------------------------------

ConfigError::ConfigError(std::string file, std::string key, int line, const std::string& reason)
    : std::runtime_error(BuildMessage(file, key, line, reason)),
      file_(std::move(file)),
      key_(std::move(key)),
      line_(line),
      reason_(reason) {}

Config ParseConfig(const std::string& yaml_text, const std::string& source_name,
                   const std::vector<std::string>& overrides) {
  DocNode root = ReadDocument(yaml_text, source_name);
  if (!overrides.empty()) {
    CheckTopLevel(root);
    std::vector<Override> parsed;
    for (const std::string& text : overrides) parsed.push_back(SplitOverride(text));
    for (const Override& o : parsed) ApplyOverride(&root, o);
    DropStaleAngles(&root, parsed);
  }
  return ParseTree(root, source_name);
}

Config LoadConfig(const std::string& path, const std::vector<std::string>& overrides) {
  namespace fs = std::filesystem;
  std::error_code error;
  if (fs::is_directory(path, error)) {
    throw ConfigError(path, "", 0, "is a directory, not a config file");
  }
  std::ifstream in(path, std::ios::binary);
  if (!in) throw ConfigError(path, "", 0, "cannot open the config file");
  std::string text(kMaxConfigBytes + 1, '\0');
  in.read(text.data(), static_cast<std::streamsize>(text.size()));
  if (in.bad()) throw ConfigError(path, "", 0, "cannot read the config file");
  text.resize(static_cast<std::size_t>(in.gcount()));
  if (text.size() > kMaxConfigBytes) {
    const std::uintmax_t size = fs::file_size(path, error);
    throw ConfigError(path, "", 0,
                      "too large: " +
                          (error ? "more than " + std::to_string(kMaxConfigBytes)
                                 : std::to_string(size)) +
                          " bytes (a config is at most " + std::to_string(kMaxConfigBytes) +
                          " bytes)");
  }
  return ParseConfig(text, path, overrides);
}

ExchangeKind EffectiveExchange(const Config& config) {
  const NetworkConfig& n = config.network;
  if (n.exchange != ExchangeKind::kAuto) return n.exchange;
  const bool plain = !n.security.enabled && !n.ros2_naming && n.discovery == DiscoveryKind::kSimple;
  return plain && config.agents.count >= kTreeFromAgents ? ExchangeKind::kTree : ExchangeKind::kAllToAll;
}

MembershipKind EffectiveMembership(const Config& config) {
  const MembershipKind m = config.network.membership;
  if (m != MembershipKind::kAuto) return m;
  return EffectiveExchange(config) == ExchangeKind::kTree && config.agents.count >= kRollCallFromAgents
             ? MembershipKind::kRollCall
             : MembershipKind::kAllPairs;
}

double EffectiveRelayLeaseS(const Config& config) {
  return config.network.relay_lease_s > 0.0 ? config.network.relay_lease_s : config.network.liveliness_lease_s;
}

int EffectiveTreeFanout(const Config& config) {
  if (config.network.tree_fanout > 0) return config.network.tree_fanout;
  const long n = std::max(1, config.agents.count);
  long f = kMinAutoFanout;
  while (1 + f + f * f < n) ++f;
  return static_cast<int>(f);
}

std::string ToYaml(const Config& config) {
  YAML::Emitter out;
  out << YAML::BeginMap;
  for (const SectionSpec& section : Sections()) {
    out << YAML::Key << section.name << YAML::Value;
    if (section.is_key) {
      EmitKeyValue(out, *section.keys.front(), &config, /*flow=*/false);
      continue;
    }
    std::vector<std::pair<std::string, const KeySpec*>> keys;
    for (const KeySpec* spec : section.keys) keys.emplace_back(spec->name, spec);
    EmitKeys(out, keys, config);
  }
  out << YAML::EndMap;
  return std::string(out.c_str()) + "\n";
}

}  // namespace deif
