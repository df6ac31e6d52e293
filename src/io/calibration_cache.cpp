#include "tofkit/io/calibration_cache.hpp"

#include <elf.h>
#include <fcntl.h>
#include <link.h>
#include <unistd.h>

#include <atomic>
#include <cerrno>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <fstream>
#include <nlohmann/json.hpp>
#include <sstream>
#include <system_error>

#include "tofkit/experiments/device_plan.hpp"
#include "tofkit/io/atomic_file.hpp"
#include "tofkit/io/config_file.hpp"
#include "tofkit/io/model_json.hpp"

namespace tofkit::io {
namespace {

constexpr const char* kEntryKind = "tofkit.factory_calibration";
constexpr int kEntryVersion = 2;  // 2: the budget beside the model

std::string environment(const char* name) {
  const char* value = std::getenv(name);
  return value == nullptr ? std::string() : std::string(value);
}

struct BuildIdSearch {
  std::uintptr_t address = 0;
  std::string id;
};

std::size_t aligned(std::size_t n, std::size_t alignment) {
  return (n + alignment - 1) / alignment * alignment;
}

// The loaded object whose PT_LOAD segments hold `address`: its PT_NOTE
// segments' NT_GNU_BUILD_ID note (owner "GNU"), as the linker's --build-id
// wrote it.
int find_build_id(dl_phdr_info* info, std::size_t, void* data) {
  auto& search = *static_cast<BuildIdSearch*>(data);
  bool holds = false;
  for (int i = 0; i < info->dlpi_phnum && !holds; ++i) {
    const ElfW(Phdr)& ph = info->dlpi_phdr[i];
    const std::uintptr_t start = info->dlpi_addr + ph.p_vaddr;
    holds = ph.p_type == PT_LOAD && search.address >= start && search.address - start < ph.p_memsz;
  }
  if (!holds) return 0;
  for (int i = 0; i < info->dlpi_phnum; ++i) {
    const ElfW(Phdr)& ph = info->dlpi_phdr[i];
    if (ph.p_type != PT_NOTE) continue;
    const std::size_t alignment = ph.p_align == 8 ? 8 : 4;
    const auto* p = reinterpret_cast<const unsigned char*>(info->dlpi_addr + ph.p_vaddr);
    std::size_t left = ph.p_memsz;
    while (left >= sizeof(ElfW(Nhdr))) {
      ElfW(Nhdr) note;
      std::memcpy(&note, p, sizeof note);
      const std::size_t name_at = sizeof note;
      const std::size_t desc_at = name_at + aligned(note.n_namesz, alignment);
      const std::size_t size = desc_at + aligned(note.n_descsz, alignment);
      if (size > left) break;
      if (note.n_type == NT_GNU_BUILD_ID && note.n_namesz == 4 &&
          std::memcmp(p + name_at, "GNU", 4) == 0 && note.n_descsz > 0) {
        static constexpr char kHex[] = "0123456789abcdef";
        for (std::size_t k = 0; k < note.n_descsz; ++k) {
          search.id += kHex[p[desc_at + k] >> 4];
          search.id += kHex[p[desc_at + k] & 15];
        }
        return 1;
      }
      p += size;
      left -= size;
    }
  }
  return 1;  // the object holding the code has no build-id
}

// FNV-1a, 64 bits: the entry's file name (the entry holds its whole key).
std::uint64_t fnv1a(std::string_view text) {
  std::uint64_t h = 14695981039346656037ull;
  for (const char c : text) {
    h ^= static_cast<unsigned char>(c);
    h *= 1099511628211ull;
  }
  return h;
}

std::string key_text(const FactoryCalibrationKey& key) {
  return "build-id " + key.build_id + "\nseed " + std::to_string(key.seed) + "\n" + key.config_text;
}

}  // namespace

std::optional<std::filesystem::path> calibration_cache_directory() {
  const std::string own = environment("TOFKIT_CACHE_DIR");
  if (own == "off") return std::nullopt;
  if (!own.empty()) return std::filesystem::path(own);
  const std::string xdg = environment("XDG_CACHE_HOME");
  if (!xdg.empty()) return std::filesystem::path(xdg) / "tofkit";
  const std::string home = environment("HOME");
  if (!home.empty()) return std::filesystem::path(home) / ".cache" / "tofkit";
  return std::nullopt;
}

std::string calibration_code_build_id() {
  static const std::string id = [] {
    BuildIdSearch search;
    search.address = reinterpret_cast<std::uintptr_t>(&experiments::factory_calibration);
    dl_iterate_phdr(find_build_id, &search);
    return search.id;
  }();
  return id;
}

device::DeviceConfig calibration_config(const device::DeviceConfig& config) {
  device::DeviceConfig c = config;
  c.scan = device::ScanConfig{};
  return c;
}

std::filesystem::path FactoryCalibrationKey::entry() const {
  char name[64];
  std::snprintf(name, sizeof name, "factory-%016llx.json",
                static_cast<unsigned long long>(fnv1a(key_text(*this))));
  return directory / name;
}

std::optional<FactoryCalibrationKey> factory_calibration_key(const std::filesystem::path& directory,
                                                             const device::DeviceConfig& config,
                                                             std::uint64_t seed,
                                                             std::string& note) {
  FactoryCalibrationKey key;
  key.build_id = calibration_code_build_id();
  if (key.build_id.empty()) {
    note = "this build has no GNU build-id (linked with --build-id=none): not cached";
    return std::nullopt;
  }
  key.directory = directory;
  key.seed = seed;
  key.config_text = dump_device_config(calibration_config(config));
  return key;
}

std::optional<FactoryCalibration> load_factory_calibration(const FactoryCalibrationKey& key,
                                                           std::string& note) {
  const std::filesystem::path entry = key.entry();
  std::ifstream in(entry, std::ios::binary);
  if (!in) {
    std::error_code ec;
    if (std::filesystem::exists(entry, ec))
      note = "cache entry " + entry.string() + " cannot be read: made again";
    return std::nullopt;
  }
  std::ostringstream text;
  text << in.rdbuf();
  try {
    const nlohmann::json j = nlohmann::json::parse(text.str());
    if (!j.is_object() || j.value("kind", "") != kEntryKind ||
        j.value("version", 0) != kEntryVersion)
      throw std::runtime_error("not a " + std::string(kEntryKind) + " entry of version " +
                               std::to_string(kEntryVersion));
    if (j.at("key").get<std::string>() != key_text(key))
      throw std::runtime_error("it holds another key");
    FactoryCalibration found{pipeline_from_json(j.at("model"), entry.string()), {}};
    if (j.contains("budget")) found.budget = budget_from_json(j.at("budget"), entry.string());
    return found;
  } catch (const std::exception& e) {
    note = "cache entry " + entry.string() + " unusable (" + e.what() + "): made again";
    return std::nullopt;
  }
}

bool store_factory_calibration(const FactoryCalibrationKey& key,
                               const FactoryCalibration& calibration, std::string& note) {
  try {
    const nlohmann::json model = pipeline_to_json(calibration.pipeline);
    const nlohmann::json budget =
        calibration.budget.empty() ? nlohmann::json(nullptr) : budget_to_json(calibration.budget);
    // The entry must give back this model and budget exactly: their JSON read
    // and written again is the same JSON (numbers in shortest round-trip form).
    const bool model_back =
        pipeline_to_json(pipeline_from_json(nlohmann::json::parse(model.dump()), "cache")).dump() ==
        model.dump();
    const bool budget_back =
        budget.is_null() ||
        budget_to_json(budget_from_json(nlohmann::json::parse(budget.dump()), "cache")).dump() ==
            budget.dump();
    if (!model_back || !budget_back) {
      note = std::string("the ") + (model_back ? "budget" : "model") +
             "'s JSON does not read back to itself: not cached";
      return false;
    }
    nlohmann::json entry = {
        {"kind", kEntryKind}, {"version", kEntryVersion}, {"key", key_text(key)}, {"model", model}};
    if (!budget.is_null()) entry["budget"] = budget;
    std::error_code ec;
    std::filesystem::create_directories(key.directory, ec);
    if (ec) {
      note = "cache directory " + key.directory.string() + " cannot be made (" + ec.message() +
             "): not cached";
      return false;
    }
    try {
      replace_file_now(key.entry(), entry.dump(1) + "\n");
    } catch (const std::exception& e) {
      note = std::string("cache entry not written (") + e.what() + "): not cached";
      return false;
    }
    return true;
  } catch (const std::exception& e) {
    note = std::string("the calibration cannot be cached (") + e.what() + ")";
    return false;
  }
}

}  // namespace tofkit::io
