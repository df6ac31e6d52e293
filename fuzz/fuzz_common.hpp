#pragma once
// Shared by the fuzz drivers: inputs that need a file are written to one
// scratch file per process (readers take paths, as the CLI gives them).
#include <unistd.h>

#include <cstddef>
#include <cstdint>
#include <filesystem>
#include <fstream>
#include <string>

namespace tofkit::fuzz {

inline std::filesystem::path scratch_file(const char* suffix, const std::uint8_t* data,
                                          std::size_t size) {
  static const std::filesystem::path path = std::filesystem::temp_directory_path() /
                                            ("tofkit_fuzz_" + std::to_string(::getpid()) + suffix);
  std::ofstream out(path, std::ios::binary | std::ios::trunc);
  out.write(reinterpret_cast<const char*>(data), static_cast<std::streamsize>(size));
  return path;
}

}  // namespace tofkit::fuzz
