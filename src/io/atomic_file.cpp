#include "tofkit/io/atomic_file.hpp"

#include <unistd.h>

#include <atomic>
#include <cerrno>
#include <cstring>
#include <fstream>
#include <stdexcept>
#include <string>
#include <system_error>

namespace tofkit::io {
namespace {

namespace fs = std::filesystem;

// A name in the target's directory (rename is atomic only within one file
// system), unique per process and call, hidden from directory listings.
fs::path temporary_path_for(const fs::path& path) {
  static std::atomic<unsigned long> counter{0};
  const std::string name = std::string(".") + path.filename().string() + ".tmp." +
                           std::to_string(::getpid()) + "." + std::to_string(counter.fetch_add(1));
  return path.parent_path() / name;
}

// Removes the temporary file unless released (exception safety).
class TemporaryFile {
 public:
  explicit TemporaryFile(fs::path path) : path_(std::move(path)) {}
  TemporaryFile(const TemporaryFile&) = delete;
  TemporaryFile& operator=(const TemporaryFile&) = delete;
  ~TemporaryFile() {
    if (!released_) {
      std::error_code ignored;
      fs::remove(path_, ignored);
    }
  }
  [[nodiscard]] const fs::path& path() const { return path_; }
  void release() { released_ = true; }

 private:
  fs::path path_;
  bool released_ = false;
};

}  // namespace

void write_file_atomically(const fs::path& path, const std::function<void(std::ostream&)>& write) {
  if (path.empty() || !path.has_filename()) {
    throw std::runtime_error("cannot write '" + path.string() + "': not a file name");
  }
  const fs::path directory = path.parent_path().empty() ? fs::path(".") : path.parent_path();
  std::error_code ec;
  if (!fs::is_directory(directory, ec)) {
    throw std::runtime_error("cannot write '" + path.string() + "': directory '" +
                             directory.string() + "' does not exist");
  }
  if (fs::is_directory(path, ec)) {
    throw std::runtime_error("cannot write '" + path.string() + "': it is a directory");
  }

  TemporaryFile temporary(temporary_path_for(path));
  {
    std::ofstream out(temporary.path(), std::ios::binary | std::ios::trunc);
    if (!out) {
      throw std::runtime_error("cannot write '" + path.string() + "': " + std::strerror(errno));
    }
    write(out);
    out.flush();
    if (!out) {
      throw std::runtime_error("cannot write '" + path.string() + "': write failed (disk full?)");
    }
    out.close();
    if (out.fail()) {
      throw std::runtime_error("cannot write '" + path.string() + "': close failed");
    }
  }
  fs::rename(temporary.path(), path, ec);
  if (ec) {
    throw std::runtime_error("cannot write '" + path.string() + "': " + ec.message());
  }
  temporary.release();
}

void write_file_atomically(const fs::path& path, std::string_view contents) {
  write_file_atomically(path, [contents](std::ostream& out) {
    out.write(contents.data(), static_cast<std::streamsize>(contents.size()));
  });
}

}  // namespace tofkit::io
