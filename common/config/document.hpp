// A configuration document as a tree, read with yaml-cpp's event parser and checked on the
// way in: the YAML features a config has no use for (anchors, aliases, merge keys, tags,
// several documents), duplicate keys at any depth, nesting beyond kMaxConfigDepth, and
// text that is not UTF-8 or holds a NUL, a control character or a tab. Every node
// remembers where it came from (a file, or a --set override), so that an error can name
// the file and the line. The schema (schema.hpp) gives the tree its meaning.
#pragma once

#include <cstddef>
#include <memory>
#include <string>
#include <string_view>
#include <vector>

namespace deif {

// The largest config document read (a file, or one override value) [bytes].
inline constexpr std::size_t kMaxConfigBytes = 1024 * 1024;
// The deepest nesting of lists and mappings accepted; the schema needs 4
// (network_sim.partitions[i].group).
inline constexpr int kMaxConfigDepth = 32;

struct DocEntry;

struct DocNode {
  enum class Kind { kNull, kScalar, kSequence, kMap };

  Kind kind = Kind::kNull;
  std::string text;     // kScalar: the text as written, without the quotes
  bool quoted = false;  // kScalar: quoted or a block scalar, so a string, never a number
  int line = 0;         // 1-based; 0 when unknown (a one-line override)
  std::shared_ptr<const std::string> source;  // what errors call the file
  std::vector<DocNode> items;     // kSequence
  std::vector<DocEntry> entries;  // kMap, in document order; no two share a key

  // The value of a key of a mapping, or nullptr (also for a node that is no mapping).
  const DocNode* Find(std::string_view key) const;
  DocNode* Find(std::string_view key);
  bool IsMap() const { return kind == Kind::kMap; }
  bool IsNull() const { return kind == Kind::kNull; }
  const std::string& SourceName() const;
  // How error messages show the node: "'5'", "the quoted string '5'", "a list", ...
  std::string Describe() const;
};

struct DocEntry {
  std::string key;
  int key_line = 0;
  DocNode value;
};

// Reads one YAML document; a text without a document (empty, or comments only) gives a
// null node. Throws ConfigError(source_name, key, line, reason) on anything refused.
DocNode ReadDocument(const std::string& text, const std::string& source_name);

}  // namespace deif
