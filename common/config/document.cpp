#include "common/config/document.hpp"

#include <yaml-cpp/eventhandler.h>
#include <yaml-cpp/exceptions.h>
#include <yaml-cpp/mark.h>
#include <yaml-cpp/parser.h>

#include <algorithm>
#include <cstdio>
#include <optional>
#include <sstream>
#include <unordered_map>
#include <utility>

#include "common/config/config.hpp"

namespace deif {

namespace {

std::string Hex(unsigned value, int digits) {
  char buffer[16];
  std::snprintf(buffer, sizeof(buffer), "%0*X", digits, value);
  return buffer;
}

// The text's problems a YAML parser would crash on, misread or silently accept: size, NUL
// bytes (a binary file, or UTF-16), invalid UTF-8, control characters and tabs (YAML
// forbids tabs in indentation; refusing them everywhere keeps the rule simple).
void CheckText(const std::string& text, const std::string& source) {
  if (text.size() > kMaxConfigBytes) {
    throw ConfigError(source, "", 0,
                      "too large: " + std::to_string(text.size()) +
                          " bytes (a config is at most " + std::to_string(kMaxConfigBytes) +
                          " bytes)");
  }
  const auto line_at = [&](std::size_t pos) {
    int line = 1;
    for (std::size_t i = 0; i < pos; ++i) line += text[i] == '\n' ? 1 : 0;
    return line;
  };
  const std::size_t nul = text.find('\0');
  if (nul != std::string::npos) {
    throw ConfigError(source, "", line_at(nul),
                      "NUL byte: not a text file (binary, or UTF-16?); a config is UTF-8 text");
  }
  std::size_t i = text.compare(0, 3, "\xEF\xBB\xBF") == 0 ? 3 : 0;  // a UTF-8 byte order mark
  int line = 1;
  while (i < text.size()) {
    const auto byte = static_cast<unsigned char>(text[i]);
    unsigned code = byte;
    std::size_t length = 1;
    if (byte >= 0x80) {
      std::size_t extra = 0;
      unsigned min = 0;
      if (byte >= 0xC2 && byte <= 0xDF) {
        extra = 1, code = byte & 0x1Fu, min = 0x80;
      } else if (byte >= 0xE0 && byte <= 0xEF) {
        extra = 2, code = byte & 0x0Fu, min = 0x800;
      } else if (byte >= 0xF0 && byte <= 0xF4) {
        extra = 3, code = byte & 0x07u, min = 0x10000;
      } else {
        throw ConfigError(source, "", line,
                          "invalid UTF-8 (byte 0x" + Hex(byte, 2) + "); a config is UTF-8 text");
      }
      for (std::size_t k = 1; k <= extra; ++k) {
        const auto next = i + k < text.size() ? static_cast<unsigned char>(text[i + k]) : 0u;
        if ((next & 0xC0u) != 0x80u) {
          throw ConfigError(source, "", line,
                            "invalid UTF-8 (byte 0x" + Hex(byte, 2) +
                                " starts a truncated sequence); a config is UTF-8 text");
        }
        code = (code << 6) | (next & 0x3Fu);
      }
      if (code < min || code > 0x10FFFF || (code >= 0xD800 && code <= 0xDFFF)) {
        throw ConfigError(source, "", line,
                          "invalid UTF-8 (overlong or surrogate sequence at byte 0x" +
                              Hex(byte, 2) + "); a config is UTF-8 text");
      }
      length = extra + 1;
    }
    if (code == '\t') {
      throw ConfigError(source, "", line, "tab character: indent with spaces, not tabs");
    }
    if ((code < 0x20 && code != '\n' && code != '\r') || code == 0x7F ||
        (code >= 0x80 && code <= 0x9F)) {
      throw ConfigError(source, "", line, "control character U+" + Hex(code, 4));
    }
    if (code == '\n') ++line;
    i += length;
  }
}

std::string JoinKey(const std::string& path, const std::string& name) {
  return path.empty() ? name : path + "." + name;
}

std::string ShowTag(const std::string& tag) {
  const std::string core = "tag:yaml.org,2002:";
  return tag.compare(0, core.size(), core) == 0 ? "!!" + tag.substr(core.size()) : tag;
}

// Whether the quoted scalar whose opening quote is at text[pos] has its closing quote
// (yaml-cpp 0.7 silently ends an unterminated one at the end of the text). A block scalar
// (| or >) has none to check.
bool QuoteClosed(const std::string& text, std::size_t pos) {
  if (pos >= text.size() || (text[pos] != '"' && text[pos] != '\'')) return true;
  const char quote = text[pos];
  for (std::size_t i = pos + 1; i < text.size(); ++i) {
    if (quote == '"' && text[i] == '\\') {
      ++i;  // an escaped character
    } else if (text[i] == quote) {
      if (quote == '\'' && i + 1 < text.size() && text[i + 1] == '\'') {
        ++i;  // '' is a quote inside a single-quoted string
      } else {
        return true;
      }
    }
  }
  return false;
}

// Builds the tree from the parser's events, refusing what a config has no use for.
//
// yaml-cpp sends odd events before it reports some syntax errors (an unclosed [ at the end
// of the text first looks like a list used as a key), so the builder only notes the first
// problem and carries on: a syntax error found later wins, else the noted problem is
// thrown at the end. Nesting too deep is thrown at once, before the recursion gets deep.
class TreeBuilder : public YAML::EventHandler {
 public:
  TreeBuilder(const std::string& text, std::shared_ptr<const std::string> source)
      : text_(text), source_(std::move(source)) {}

  DocNode TakeRoot() {
    if (error_) throw *error_;
    return root_ ? std::move(*root_) : Null(0);
  }

  void OnDocumentStart(const YAML::Mark& mark) override {
    if (documents_++ == 0) {
      first_document_pos_ = mark.pos;
    } else if (mark.pos == first_document_pos_) {
      // yaml-cpp makes empty documents without moving on at a stray ',' at the top level.
      const auto pos = static_cast<std::size_t>(mark.pos);
      Fail(LineOf(mark), "",
           "YAML syntax error: unexpected '" +
               (pos < text_.size() ? std::string(1, text_[pos]) : std::string("end")) + "'");
    } else {
      Fail(LineOf(mark), "", "a second YAML document ('---'): a config is one document");
    }
  }
  void OnDocumentEnd() override {}

  void OnNull(const YAML::Mark& mark, YAML::anchor_t anchor) override {
    CheckAnchor(mark, anchor);
    Attach(Null(LineOf(mark)));
  }

  void OnAlias(const YAML::Mark& mark, YAML::anchor_t /*anchor*/) override {
    Fail(LineOf(mark), ChildPath(),
         "YAML aliases (*name) are not supported: write the value out");
    Attach(Null(LineOf(mark)));
  }

  void OnScalar(const YAML::Mark& mark, const std::string& tag, YAML::anchor_t anchor,
                const std::string& value) override {
    CheckAnchor(mark, anchor);
    if (tag != "?" && tag != "!") {
      Fail(LineOf(mark), ChildPath(),
           "YAML tags (" + ShowTag(tag) + ") are not supported: write the value plainly");
    }
    if (tag == "!" && !mark.is_null() && !QuoteClosed(text_, static_cast<std::size_t>(mark.pos))) {
      Fail(LineOf(mark), ChildPath(), "YAML syntax error: a quoted string is never closed");
    }
    DocNode node = Null(LineOf(mark));
    node.kind = DocNode::Kind::kScalar;
    node.text = value;
    node.quoted = tag == "!";
    Attach(std::move(node));
  }

  void OnSequenceStart(const YAML::Mark& mark, const std::string& tag, YAML::anchor_t anchor,
                       YAML::EmitterStyle::value /*style*/) override {
    Open(mark, tag, anchor, DocNode::Kind::kSequence);
  }
  void OnSequenceEnd() override { Close(); }

  void OnMapStart(const YAML::Mark& mark, const std::string& tag, YAML::anchor_t anchor,
                  YAML::EmitterStyle::value /*style*/) override {
    Open(mark, tag, anchor, DocNode::Kind::kMap);
  }
  void OnMapEnd() override { Close(); }

  void OnAnchor(const YAML::Mark& mark, const std::string& name) override {
    Fail(LineOf(mark), ChildPath(),
         "YAML anchors (&" + name + ") are not supported: write the value out");
  }

 private:
  // A list or mapping being read, with the dotted path that names it in messages.
  struct Frame {
    DocNode node;
    std::string path;
    bool have_key = false;  // a mapping: its next node is the value of `key`
    std::string key;
    int key_line = 0;
    std::unordered_map<std::string, int> seen;  // a mapping's keys so far, and their lines
  };

  static int LineOf(const YAML::Mark& mark) { return mark.is_null() ? 0 : mark.line + 1; }

  DocNode Null(int line) const {
    DocNode node;
    node.line = line;
    node.source = source_;
    return node;
  }

  // Notes the first problem (see the class comment).
  void Fail(int line, const std::string& key, const std::string& reason) {
    if (!error_) error_.emplace(*source_, key, line, reason);
  }

  // The path of the node the next event makes.
  std::string ChildPath() const {
    if (stack_.empty()) return "";
    const Frame& top = stack_.back();
    if (top.node.kind == DocNode::Kind::kSequence) {
      return top.path + "[" + std::to_string(top.node.items.size()) + "]";
    }
    return top.have_key ? JoinKey(top.path, top.key) : top.path;
  }

  bool ExpectingKey() const {
    return !stack_.empty() && stack_.back().node.kind == DocNode::Kind::kMap &&
           !stack_.back().have_key;
  }

  void CheckAnchor(const YAML::Mark& mark, YAML::anchor_t anchor) {
    if (anchor != YAML::NullAnchor) {
      Fail(LineOf(mark), ChildPath(),
           "YAML anchors (&name) are not supported: write the value out");
    }
  }

  void Open(const YAML::Mark& mark, const std::string& tag, YAML::anchor_t anchor,
            DocNode::Kind kind) {
    CheckAnchor(mark, anchor);
    const int line = LineOf(mark);
    if (ExpectingKey()) {
      Fail(line, stack_.back().path,
           std::string("keys must be plain names (got ") +
               (kind == DocNode::Kind::kMap ? "a mapping" : "a list") + ")");
    }
    if (tag != "?") {
      Fail(line, ChildPath(),
           "YAML tags (" + ShowTag(tag) + ") are not supported: write the value plainly");
    }
    if (static_cast<int>(stack_.size()) >= kMaxConfigDepth) {
      throw ConfigError(*source_, ChildPath(), line,
                        "nested deeper than " + std::to_string(kMaxConfigDepth) +
                            " levels of lists and mappings");
    }
    Frame frame;
    frame.path = ChildPath();
    frame.node = Null(line);
    frame.node.kind = kind;
    stack_.push_back(std::move(frame));
  }

  void Close() {
    DocNode node = std::move(stack_.back().node);
    stack_.pop_back();
    Attach(std::move(node));
  }

  void Attach(DocNode node) {
    if (stack_.empty()) {
      root_ = std::move(node);
      return;
    }
    Frame& top = stack_.back();
    if (top.node.kind == DocNode::Kind::kSequence) {
      top.node.items.push_back(std::move(node));
      return;
    }
    if (!top.have_key) {
      if (node.kind != DocNode::Kind::kScalar) {
        Fail(node.line, top.path, "keys must be plain names (got " + node.Describe() + ")");
        return;  // dropped; the noted problem is thrown in the end
      }
      if (node.text == "<<" && !node.quoted) {
        Fail(node.line, top.path,
             "YAML merge keys (<<) are not supported: write the keys out");
      }
      const auto [it, inserted] = top.seen.emplace(node.text, node.line);
      if (!inserted) {
        Fail(node.line, JoinKey(top.path, node.text),
             "duplicate key (first at line " + std::to_string(it->second) + ")");
      }
      top.have_key = true;
      top.key = node.text;
      top.key_line = node.line;
      return;
    }
    // An empty value's mark is where the parser looked next: name the key's line instead.
    if (node.kind == DocNode::Kind::kNull) node.line = top.key_line;
    top.node.entries.push_back(DocEntry{top.key, top.key_line, std::move(node)});
    top.have_key = false;
  }

  const std::string& text_;
  std::shared_ptr<const std::string> source_;
  std::optional<ConfigError> error_;
  std::vector<Frame> stack_;
  std::optional<DocNode> root_;
  int documents_ = 0;
  int first_document_pos_ = 0;
};

}  // namespace

const DocNode* DocNode::Find(std::string_view key) const {
  if (kind != Kind::kMap) return nullptr;
  for (const DocEntry& entry : entries) {
    if (entry.key == key) return &entry.value;
  }
  return nullptr;
}

DocNode* DocNode::Find(std::string_view key) {
  return const_cast<DocNode*>(static_cast<const DocNode*>(this)->Find(key));
}

const std::string& DocNode::SourceName() const {
  static const std::string kNone;
  return source ? *source : kNone;
}

std::string DocNode::Describe() const {
  switch (kind) {
    case Kind::kNull:
      return "nothing (null)";
    case Kind::kSequence:
      return "a list";
    case Kind::kMap:
      return "a mapping";
    case Kind::kScalar:
      return quoted ? "the quoted string '" + text + "'" : "'" + text + "'";
  }
  return "nothing";
}

DocNode ReadDocument(const std::string& text, const std::string& source_name) {
  CheckText(text, source_name);
  auto source = std::make_shared<const std::string>(source_name);
  // Without a byte order mark, the parser's marks are offsets into `body`.
  const std::string body = text.compare(0, 3, "\xEF\xBB\xBF") == 0 ? text.substr(3) : text;
  std::istringstream in(body);
  TreeBuilder builder(body, source);
  try {
    YAML::Parser parser(in);
    // One document, and a look for a second one (the builder refuses it as it starts).
    if (parser.HandleNextDocument(builder)) parser.HandleNextDocument(builder);
  } catch (const YAML::Exception& e) {
    // At the end of the text the parser names the line after the last one: name the last.
    const int last_line = static_cast<int>(std::count(body.begin(), body.end(), '\n')) +
                          (body.empty() || body.back() == '\n' ? 0 : 1);
    const int line = e.mark.is_null() ? 0 : std::min(e.mark.line + 1, std::max(last_line, 1));
    throw ConfigError(source_name, "", line, "YAML syntax error: " + e.msg);
  }
  return builder.TakeRoot();
}

}  // namespace deif
