#include "tofkit/io/config_file.hpp"

#include <fmt/format.h>
#include <toml++/toml.h>

#include <algorithm>
#include <cctype>
#include <charconv>
#include <climits>
#include <cmath>
#include <fstream>
#include <sstream>
#include <type_traits>
#include <utility>

#include "tofkit/device/config_limits.hpp"
#include "tofkit/io/edit_distance.hpp"
#include "tofkit/io/input_file.hpp"

namespace tofkit::io {
namespace {

namespace fs = std::filesystem;
using device::ConfigField;
using device::DeviceConfig;

constexpr std::string_view kSetOrigin = "--set";
constexpr std::size_t kMaxConfigBytes = 1u << 20;
constexpr std::size_t kMaxConfigDepth = 16;
constexpr std::size_t kMaxConfigDots = 64;

std::string_view trim(std::string_view s) {
  while (!s.empty() && (s.front() == ' ' || s.front() == '\t')) s.remove_prefix(1);
  while (!s.empty() && (s.back() == ' ' || s.back() == '\t')) s.remove_suffix(1);
  return s;
}

std::string section_of(std::string_view key) {
  return std::string(key.substr(0, key.find('.')));
}

std::string member_of(std::string_view key) {
  const auto dot = key.find('.');
  return std::string(dot == std::string_view::npos ? key : key.substr(dot + 1));
}

// Closest known name, if close enough to be a likely typo; an exact member
// name in the wrong section is suggested too.
std::string suggestion(std::string_view unknown, const std::vector<std::string>& known,
                       bool match_members) {
  // Edit distance costs |unknown| x |known|: no suggestion for a name no key resembles.
  if (unknown.size() > 64) return std::string();
  std::string best;
  std::size_t best_distance = std::max<std::size_t>(2, unknown.size() / 3) + 1;
  for (const auto& k : known) {
    std::size_t d = edit_distance(unknown, k);
    if (match_members) d = std::min(d, edit_distance(member_of(unknown), member_of(k)));
    if (d < best_distance) {
      best_distance = d;
      best = k;
    }
  }
  return best.empty() ? std::string() : " (did you mean " + best + "?)";
}

std::string_view type_name(toml::node_type type) {
  switch (type) {
    case toml::node_type::table:
      return "a table";
    case toml::node_type::array:
      return "an array";
    case toml::node_type::string:
      return "a string";
    case toml::node_type::integer:
      return "an integer";
    case toml::node_type::floating_point:
      return "a floating-point number";
    case toml::node_type::boolean:
      return "a boolean";
    case toml::node_type::date:
      return "a date";
    case toml::node_type::time:
      return "a time";
    case toml::node_type::date_time:
      return "a date-time";
    default:
      return "nothing";
  }
}

std::string expected_type(const ConfigField& field) {
  if (std::holds_alternative<bool*>(field.value)) return "a boolean (true or false)";
  if (std::holds_alternative<int*>(field.value)) return "an integer";
  return "a number";
}

std::string number_text(double v) {
  return fmt::format("{}", v);
}

// A value about to be stored in a field, from TOML or from --set.
struct Parsed {
  bool ok = false;
  double number = 0;  // for double and int fields
  bool boolean = false;
  std::string error;  // when !ok
};

// Store into an int field: integral and within int (range checks come later,
// from validate(), except for values int cannot hold).
Parsed as_int(const ConfigField& field, double v) {
  Parsed p;
  if (!std::isfinite(v) || v != std::floor(v)) {
    p.error = "expected an integer, got " + number_text(v);
  } else if (v < static_cast<double>(INT_MIN) || v > static_cast<double>(INT_MAX)) {
    p.error = field.key + " = " + number_text(v) + " is out of range [" + number_text(field.min) +
              ", " + number_text(field.max) + "]";
  } else {
    p.ok = true;
    p.number = v;
  }
  return p;
}

Parsed from_toml(const ConfigField& field, const toml::node& node) {
  Parsed p;
  const bool is_number = node.is_integer() || node.is_floating_point();
  const double number = node.is_integer()          ? static_cast<double>(node.as_integer()->get())
                        : node.is_floating_point() ? node.as_floating_point()->get()
                                                   : 0.0;
  if (std::holds_alternative<bool*>(field.value)) {
    if (node.is_boolean()) {
      p.ok = true;
      p.boolean = node.as_boolean()->get();
      return p;
    }
  } else if (is_number) {
    if (std::holds_alternative<int*>(field.value)) return as_int(field, number);
    p.ok = true;
    p.number = number;
    return p;
  }
  p.error = "wrong type for " + field.key + ": expected " + expected_type(field) + ", got " +
            std::string(type_name(node.type()));
  return p;
}

bool parse_double(std::string_view text, double& out) {
  const std::string_view digits = !text.empty() && text.front() == '+' ? text.substr(1) : text;
  if (digits.empty()) return false;
  const auto [ptr, ec] = std::from_chars(digits.data(), digits.data() + digits.size(), out);
  return ec == std::errc() && ptr == digits.data() + digits.size();
}

Parsed from_text(const ConfigField& field, std::string_view text) {
  Parsed p;
  std::string quoted = "'";
  quoted.append(text);
  quoted += '\'';
  if (std::holds_alternative<bool*>(field.value)) {
    if (text == "true" || text == "1") {
      p.ok = true;
      p.boolean = true;
    } else if (text == "false" || text == "0") {
      p.ok = true;
      p.boolean = false;
    } else {
      p.error =
          "wrong type for " + field.key + ": expected " + expected_type(field) + ", got " + quoted;
    }
    return p;
  }
  double v = 0;
  if (!parse_double(text, v)) {
    p.error =
        "wrong type for " + field.key + ": expected " + expected_type(field) + ", got " + quoted;
    return p;
  }
  if (std::holds_alternative<int*>(field.value)) return as_int(field, v);
  p.ok = true;
  p.number = v;
  return p;
}

void store(const ConfigField& field, const Parsed& p) {
  std::visit(
      [&](auto* ptr) {
        using T = std::remove_pointer_t<decltype(ptr)>;
        if constexpr (std::is_same_v<T, bool>) {
          *ptr = p.boolean;
        } else {
          *ptr = static_cast<T>(p.number);
        }
      },
      field.value);
}

std::string toml_value_text(const toml::node& node) {
  if (node.is_integer()) return fmt::format("{}", node.as_integer()->get());
  if (node.is_floating_point()) return number_text(node.as_floating_point()->get());
  if (node.is_boolean()) return node.as_boolean()->get() ? "true" : "false";
  if (node.is_string()) return "\"" + node.as_string()->get() + "\"";
  return std::string(type_name(node.type()));
}

DeviceConfig preset_or_throw(std::string_view name, const std::string& origin) {
  try {
    return device::preset(name);
  } catch (const std::invalid_argument& e) {
    throw ConfigError(origin + ": " + e.what());
  }
}

std::string join_lines(const std::vector<std::string>& lines) {
  std::string all;
  for (const auto& l : lines) all += (all.empty() ? "" : "\n") + l;
  return all;
}

}  // namespace

void check_toml_shape(std::string_view text, const std::string& name) {
  if (text.size() > kMaxConfigBytes) {
    throw ConfigError(fmt::format("{}: {} bytes, more than a config file may have ({})", name,
                                  text.size(), kMaxConfigBytes));
  }
  // A lexical pass outside strings and comments: bracket depth and dots per line.
  std::size_t line = 1, column = 0, depth = 0, dots = 0;
  char quote = 0;          // inside a string: its quote character
  bool multiline = false;  // inside a """ or ''' string
  bool comment = false;
  auto fail = [&](const std::string& what) {
    throw ConfigError(fmt::format("{}:{}:{}: {}", name, line, column, what));
  };
  for (std::size_t i = 0; i < text.size(); ++i) {
    const char c = text[i];
    ++column;
    if (c == '\n') {
      ++line;
      column = 0;
      dots = 0;
      comment = false;
      if (quote != 0 && !multiline) quote = 0;  // unterminated: the parser reports it
      continue;
    }
    if (comment) continue;
    if (quote != 0) {
      if (c == '\\' && quote == '"') {
        ++i;
        ++column;
      } else if (c == quote) {
        if (!multiline) {
          quote = 0;
        } else if (text.substr(i, 3) == std::string(3, quote)) {
          quote = 0;
          multiline = false;
          i += 2;
          column += 2;
        }
      }
      continue;
    }
    switch (c) {
      case '#':
        comment = true;
        break;
      case '"':
      case '\'':
        quote = c;
        multiline = text.substr(i, 3) == std::string(3, c);
        if (multiline) {
          i += 2;
          column += 2;
        }
        break;
      case '[':
      case '{':
        if (++depth > kMaxConfigDepth) {
          fail(fmt::format("nesting deeper than {} levels (a config file has sections of keys)",
                           kMaxConfigDepth));
        }
        break;
      case ']':
      case '}':
        if (depth > 0) --depth;
        break;
      case '.':
        if (++dots > kMaxConfigDots) {
          fail(fmt::format("more than {} dots on one line (keys are section.key)", kMaxConfigDots));
        }
        break;
      default:
        break;
    }
  }
}

namespace {

toml::table parse_toml_file(const fs::path& file) {
  std::string text;
  try {
    text = read_text_file(file, "config file");
  } catch (const std::runtime_error& e) {
    throw ConfigError(e.what());
  }
  check_toml_shape(text, file.string());
  try {
    return toml::parse(text, file.string());
  } catch (const toml::parse_error& e) {
    throw ConfigError(fmt::format("{}:{}:{}: TOML syntax error: {}", file.string(),
                                  e.source().begin.line, e.source().begin.column, e.description()));
  }
}

class Loader {
 public:
  explicit Loader(LoadedDeviceConfig& result) : result_(result) {}

  // Point the key registry at the config (after the preset is chosen).
  void bind() {
    fields_ = device::config_fields(result_.config);
    keys_.clear();
    sections_.clear();
    for (const auto& f : fields_) {
      keys_.push_back(f.key);
      const std::string s = section_of(f.key);
      if (std::find(sections_.begin(), sections_.end(), s) == sections_.end()) {
        sections_.push_back(s);
      }
    }
  }

  void apply_table(const toml::table& root, const std::string& file) {
    for (auto&& [name, node] : root) {
      const std::string where = file + ":" + std::to_string(node.source().begin.line);
      const std::string section(name.str());
      if (section == "preset") continue;  // handled by the caller
      const toml::table* table = node.as_table();
      const bool known_section =
          std::find(sections_.begin(), sections_.end(), section) != sections_.end();
      if (!known_section) {
        if (table != nullptr) {
          errors_.push_back(where + ": unknown section [" + section + "]" +
                            suggestion(section, sections_, false));
        } else {
          errors_.push_back(where + ": unknown key '" + section + "'" +
                            suggestion(section, keys_, true));
        }
        continue;
      }
      if (table == nullptr) {
        errors_.push_back(where + ": '" + section + "' must be a table ([" + section + "]), got " +
                          std::string(type_name(node.type())));
        continue;
      }
      for (auto&& [member, value] : *table) {
        const std::string key = section + "." + std::string(member.str());
        const std::string value_where = file + ":" + std::to_string(value.source().begin.line);
        const ConfigField* field = find(key);
        if (field == nullptr) {
          errors_.push_back(value_where + ": unknown key '" + key + "'" +
                            suggestion(key, keys_, true));
          continue;
        }
        const Parsed p = from_toml(*field, value);
        if (!p.ok) {
          errors_.push_back(value_where + ": " + p.error);
          continue;
        }
        store(*field, p);
        result_.sources.push_back(ConfigSource{key, toml_value_text(value), value_where});
      }
    }
  }

  void apply_override(const std::string& assignment) {
    const auto eq = assignment.find('=');
    if (eq == std::string::npos) {
      errors_.push_back("--set '" + assignment + "': expected section.key=value");
      return;
    }
    const std::string key(trim(std::string_view(assignment).substr(0, eq)));
    const std::string_view text = trim(std::string_view(assignment).substr(eq + 1));
    const ConfigField* field = find(key);
    if (field == nullptr) {
      errors_.push_back("--set " + assignment + ": unknown key '" + key + "'" +
                        suggestion(key, keys_, true));
      return;
    }
    const Parsed p = from_text(*field, text);
    if (!p.ok) {
      errors_.push_back("--set " + assignment + ": " + p.error);
      return;
    }
    store(*field, p);
    result_.sources.push_back(ConfigSource{key, std::string(text), std::string(kSetOrigin)});
  }

  // Throws the collected parse errors, then the range errors naming where
  // each offending value came from.
  void finish() {
    if (!errors_.empty()) throw ConfigError(join_lines(errors_));
    for (const auto& message : device::validate(result_.config)) {
      errors_.push_back(blame(mentioned_keys(message)) + ": " + message);
    }
    if (!errors_.empty()) throw ConfigError(join_lines(errors_));
    for (const auto& violation : device::check_config_limits(result_.config)) {
      errors_.push_back(blame(violation.keys) + ": " + violation.message);
    }
    if (!errors_.empty()) throw ConfigError(join_lines(errors_));
  }

  // Where the values of `keys` came from: the user's assignments of them
  // ("--set laser.repetition_hz=1e9", "dev.toml:7 (laser.repetition_hz)"), else the preset.
  std::string blame(const std::vector<std::string>& keys) const {
    std::string origins;
    for (const auto& key : keys) {
      const ConfigSource* last = nullptr;
      for (const auto& s : result_.sources) {
        if (s.key == key) last = &s;  // the last assignment wins
      }
      if (last == nullptr) continue;
      if (!origins.empty()) origins += ", ";
      origins += last->origin == kSetOrigin ? "--set " + key + "=" + last->value
                                            : last->origin + " (" + key + ")";
    }
    return origins.empty() ? "preset '" + result_.config.name + "'" : origins;
  }

  // The registered keys a message names, in order of appearance.
  std::vector<std::string> mentioned_keys(const std::string& message) const {
    auto is_name_char = [](char c) {
      return std::isalnum(static_cast<unsigned char>(c)) != 0 || c == '_' || c == '.';
    };
    std::vector<std::pair<std::size_t, std::string>> found;
    for (const auto& key : keys_) {
      for (std::size_t at = message.find(key); at != std::string::npos;
           at = message.find(key, at + 1)) {
        const std::size_t end = at + key.size();
        if ((at == 0 || !is_name_char(message[at - 1])) &&
            (end == message.size() || !is_name_char(message[end]) || message[end] == '.')) {
          found.emplace_back(at, key);
          break;
        }
      }
    }
    std::sort(found.begin(), found.end());
    std::vector<std::string> keys;
    for (auto& f : found) keys.push_back(std::move(f.second));
    return keys;
  }

 private:
  const ConfigField* find(std::string_view key) const {
    for (const auto& f : fields_) {
      if (f.key == key) return &f;
    }
    return nullptr;
  }

  LoadedDeviceConfig& result_;
  std::vector<ConfigField> fields_;
  std::vector<std::string> keys_;
  std::vector<std::string> sections_;
  std::vector<std::string> errors_;
};

}  // namespace

LoadedDeviceConfig load_device_config_traced(std::string_view preset,
                                             const std::optional<fs::path>& file,
                                             std::span<const std::string> overrides) {
  LoadedDeviceConfig result;
  std::optional<toml::table> root;
  if (file) root = parse_toml_file(*file);

  // Choose the preset: --preset, else the file's `preset = "..."`, else paper.
  std::string preset_name(preset);
  result.preset_origin = preset.empty() ? "default" : "--preset";
  if (root) {
    if (const toml::node* node = root->get("preset")) {
      const std::string where = file->string() + ":" + std::to_string(node->source().begin.line);
      if (!node->is_string()) {
        throw ConfigError(where + ": wrong type for preset: expected a string, got " +
                          std::string(type_name(node->type())));
      }
      const std::string& named = node->as_string()->get();
      if (!preset.empty() && named != preset) {
        throw ConfigError(where + ": preset \"" + named + "\" conflicts with --preset " +
                          std::string(preset));
      }
      if (preset.empty()) {
        preset_name = named;
        result.preset_origin = where;
      }
    }
  }
  if (preset_name.empty()) preset_name = "paper";
  result.config = preset_or_throw(preset_name, result.preset_origin);

  Loader loader(result);
  loader.bind();
  if (root) loader.apply_table(*root, file->string());
  for (const auto& assignment : overrides) loader.apply_override(assignment);
  loader.finish();
  return result;
}

DeviceConfig load_device_config(std::string_view preset, const std::optional<fs::path>& file,
                                std::span<const std::string> overrides) {
  return load_device_config_traced(preset, file, overrides).config;
}

std::string dump_device_config(const DeviceConfig& config) {
  DeviceConfig copy = config;
  const auto names = device::preset_names();
  const bool known = std::find(names.begin(), names.end(), config.name) != names.end();
  std::string out;
  out += "# tofkit device configuration: every key, its unit in its name.\n";
  out += "# Use with: tofkit --config FILE <command>; override with --set section.key=value.\n";
  if (known) {
    out += fmt::format("preset = \"{}\"\n", config.name);
  } else {
    out += fmt::format("# name: {}\n", config.name);
  }
  std::string section;
  for (const auto& f : device::config_fields(copy)) {
    if (section_of(f.key) != section) {
      section = section_of(f.key);
      out += fmt::format("\n[{}]\n", section);
    }
    std::string value;
    std::string range;
    if (const auto* b = std::get_if<bool*>(&f.value)) {
      value = **b ? "true" : "false";
      range = "true or false";
    } else if (const auto* i = std::get_if<int*>(&f.value)) {
      value = fmt::format("{}", **i);
      range = fmt::format("[{}, {}]", f.min, f.max);
    } else {
      value = number_text(*std::get<double*>(f.value));
      // TOML needs a '.' or an exponent to read a float back as a float.
      if (value.find_first_of(".eEni") == std::string::npos) value += ".0";
      range = device::range_text(f);
    }
    out += fmt::format("# {}. Valid: {}\n{} = {}\n", f.description, range, member_of(f.key), value);
  }
  return out;
}

}  // namespace tofkit::io
