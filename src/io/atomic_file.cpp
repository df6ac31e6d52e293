#include "tofkit/io/atomic_file.hpp"

#include <fcntl.h>
#include <sys/stat.h>
#include <unistd.h>

#include <array>
#include <atomic>
#include <cerrno>
#include <csignal>
#include <cstdlib>
#include <cstring>
#include <fstream>
#include <mutex>
#include <stdexcept>
#include <string>
#include <system_error>
#include <utility>
#include <vector>

namespace tofkit::io {
namespace {

namespace fs = std::filesystem;

// ---- temporaries removed on SIGINT / SIGTERM ------------------------------
// The handler may only call async-signal-safe functions: the live temporaries
// are kept as C strings in a fixed table of atomic pointers.
constexpr std::size_t kSignalSlots = 1024;
std::array<std::atomic<char*>, kSignalSlots> g_live_temporaries{};

// Directories the open transaction created (removed on rollback), for the
// handler likewise.
constexpr std::size_t kDirectorySlots = 256;
std::array<std::atomic<char*>, kDirectorySlots> g_created_directories{};

extern "C" void remove_temporaries_and_reraise(int signal_number) {
  for (auto& slot : g_live_temporaries) {
    if (char* path = slot.load()) ::unlink(path);
  }
  // Then the directories the command created, now empty unless something
  // else wrote there (rmdir removes only empty ones): innermost first, so
  // repeat while a pass removes one.
  for (bool removed = true; removed;) {
    removed = false;
    for (auto& slot : g_created_directories) {
      if (char* path = slot.exchange(nullptr)) {
        if (::rmdir(path) == 0) {
          removed = true;
        } else {
          slot.store(path);
        }
      }
    }
  }
  std::signal(signal_number, SIG_DFL);
  std::raise(signal_number);
}

void install_signal_handlers() {
  static std::once_flag once;
  std::call_once(once, [] {
    for (int s : {SIGINT, SIGTERM}) {
      struct sigaction current {};
      if (::sigaction(s, nullptr, &current) != 0) continue;
      if (current.sa_handler != SIG_DFL) continue;  // someone else handles it
      struct sigaction action {};
      action.sa_handler = remove_temporaries_and_reraise;
      sigemptyset(&action.sa_mask);
      ::sigaction(s, &action, nullptr);
    }
  });
}

// Returns the slot index, or kSignalSlots when the table is full (the file is
// then only removed by the normal paths).
std::size_t register_temporary(const fs::path& path) {
  install_signal_handlers();
  const std::string text = path.string();
  char* copy = static_cast<char*>(std::malloc(text.size() + 1));
  if (copy == nullptr) return kSignalSlots;
  std::memcpy(copy, text.c_str(), text.size() + 1);
  for (std::size_t i = 0; i < kSignalSlots; ++i) {
    char* expected = nullptr;
    if (g_live_temporaries[i].compare_exchange_strong(expected, copy)) return i;
  }
  std::free(copy);
  return kSignalSlots;
}

void unregister_temporary(std::size_t slot) {
  if (slot < kSignalSlots) std::free(g_live_temporaries[slot].exchange(nullptr));
}

void register_created_directory(const fs::path& path) {
  install_signal_handlers();
  const std::string text = path.string();
  char* copy = static_cast<char*>(std::malloc(text.size() + 1));
  if (copy == nullptr) return;
  std::memcpy(copy, text.c_str(), text.size() + 1);
  for (auto& slot : g_created_directories) {
    char* expected = nullptr;
    if (slot.compare_exchange_strong(expected, copy)) return;
  }
  std::free(copy);
}

// The transaction ended (committed or rolled back): its directories are no
// longer the handler's to remove.
void forget_created_directories() {
  for (auto& slot : g_created_directories) std::free(slot.exchange(nullptr));
}

// A temporary file: removed unless renamed, and known to the signal handler
// meanwhile.
class Temporary {
 public:
  explicit Temporary(fs::path path) : path_(std::move(path)), slot_(register_temporary(path_)) {}
  Temporary(const Temporary&) = delete;
  Temporary& operator=(const Temporary&) = delete;
  Temporary(Temporary&& other) noexcept
      : path_(std::move(other.path_)),
        slot_(std::exchange(other.slot_, kSignalSlots)),
        owned_(std::exchange(other.owned_, false)) {}
  ~Temporary() { discard(); }

  [[nodiscard]] const fs::path& path() const { return path_; }

  void rename_to(const fs::path& target) {
    std::error_code ec;
    fs::rename(path_, target, ec);
    if (ec) throw std::runtime_error("cannot write '" + target.string() + "': " + ec.message());
    owned_ = false;
    unregister_temporary(std::exchange(slot_, kSignalSlots));
  }

  void discard() noexcept {
    if (owned_) {
      std::error_code ignored;
      fs::remove(path_, ignored);
      owned_ = false;
    }
    unregister_temporary(std::exchange(slot_, kSignalSlots));
  }

 private:
  fs::path path_;
  std::size_t slot_;
  bool owned_ = true;
};

// A name in the target's directory (rename is atomic only within one file
// system), unique per process and call, hidden from directory listings.
fs::path temporary_path_for(const fs::path& path) {
  static std::atomic<unsigned long> counter{0};
  const std::string name = std::string(".") + path.filename().string() + ".tmp." +
                           std::to_string(::getpid()) + "." + std::to_string(counter.fetch_add(1));
  return path.parent_path() / name;
}

// ---- inputs and the open transaction --------------------------------------
struct FileIdentity {
  dev_t device;
  ino_t inode;
  std::string name;
};

struct Staged {
  Temporary temporary;
  fs::path target;
};

struct State {
  std::mutex mutex;
  std::vector<FileIdentity> inputs;
  bool open = false;
  std::vector<Staged> staged;
  std::vector<fs::path> created_directories;  // outermost first
};

State& state() {
  static State s;
  return s;
}

[[noreturn]] void refuse(const fs::path& path, const std::string& why) {
  throw std::runtime_error("cannot write '" + path.string() + "': " + why);
}

// Every check that must pass before anything is written to `path`.
void check_target(const fs::path& path) {
  if (path.empty() || !path.has_filename()) refuse(path, "not a file name");
  const fs::path directory = path.parent_path().empty() ? fs::path(".") : path.parent_path();
  std::error_code ec;
  if (!fs::is_directory(directory, ec)) {
    refuse(path, "directory '" + directory.string() + "' does not exist");
  }
  struct stat link_info {};
  if (::lstat(path.c_str(), &link_info) == 0) {
    if (S_ISDIR(link_info.st_mode)) refuse(path, "it is a directory");
    if (S_ISLNK(link_info.st_mode)) {
      refuse(path, "it is a symbolic link (tofkit does not replace links; remove it first)");
    }
    if (!S_ISREG(link_info.st_mode)) {
      refuse(path, "it exists and is not a regular file (a device, FIFO or socket)");
    }
    auto& s = state();
    const std::scoped_lock lock(s.mutex);
    for (const auto& input : s.inputs) {
      struct stat now {};  // the input still there under its name (inodes get reused)
      if (input.device == link_info.st_dev && input.inode == link_info.st_ino &&
          ::stat(input.name.c_str(), &now) == 0 && now.st_dev == input.device &&
          now.st_ino == input.inode) {
        refuse(path, "it is the input file '" + input.name +
                         "'; choose another output path so the input is kept");
      }
    }
  }
  auto& s = state();
  const std::scoped_lock lock(s.mutex);
  for (const auto& staged : s.staged) {
    if (staged.target == path) refuse(path, "written twice by one command");
  }
}

void stage_or_rename(Temporary temporary, const fs::path& target) {
  auto& s = state();
  {
    const std::scoped_lock lock(s.mutex);
    if (s.open) {
      s.staged.push_back(Staged{std::move(temporary), target});
      return;
    }
  }
  temporary.rename_to(target);
}

}  // namespace

namespace {

// The content written to a new temporary beside `path` (removed again if
// anything fails, and by the signal handler meanwhile).
Temporary write_temporary(const fs::path& path, const std::function<void(std::ostream&)>& write) {
  Temporary temporary(temporary_path_for(path));
  std::ofstream out(temporary.path(), std::ios::binary | std::ios::trunc);
  if (!out) refuse(path, std::strerror(errno));
  write(out);
  out.flush();
  if (!out) refuse(path, "write failed (disk full?)");
  out.close();
  if (out.fail()) refuse(path, "close failed");
  return temporary;
}

std::function<void(std::ostream&)> writer_of(std::string_view contents) {
  return [contents](std::ostream& out) {
    out.write(contents.data(), static_cast<std::streamsize>(contents.size()));
  };
}

}  // namespace

void write_file_atomically(const fs::path& path, const std::function<void(std::ostream&)>& write) {
  check_target(path);
  stage_or_rename(write_temporary(path, write), path);
}

void replace_file_now(const fs::path& path, std::string_view contents) {
  write_temporary(path, writer_of(contents)).rename_to(path);
}

void write_file_atomically(const fs::path& path, std::string_view contents) {
  write_file_atomically(path, writer_of(contents));
}

void adopt_written_file(const fs::path& written, const fs::path& target) {
  Temporary temporary(written);
  check_target(target);
  stage_or_rename(std::move(temporary), target);
}

fs::path staged_path(const fs::path& target) {
  auto& s = state();
  const std::scoped_lock lock(s.mutex);
  for (const auto& staged : s.staged) {
    if (staged.target == target) return staged.temporary.path();
  }
  return target;
}

OutputTransaction::OutputTransaction() {
  auto& s = state();
  const std::scoped_lock lock(s.mutex);
  if (s.open) throw std::logic_error("OutputTransaction: one is already open");
  s.open = true;
}

OutputTransaction::~OutputTransaction() {
  auto& s = state();
  const std::scoped_lock lock(s.mutex);
  s.staged.clear();  // each Temporary removes its file
  for (auto it = s.created_directories.rbegin(); it != s.created_directories.rend(); ++it) {
    std::error_code ignored;
    fs::remove(*it, ignored);  // only succeeds while empty
  }
  s.created_directories.clear();
  forget_created_directories();
  s.inputs.clear();
  s.open = false;
}

void OutputTransaction::commit() {
  auto& s = state();
  const std::scoped_lock lock(s.mutex);
  std::vector<Staged> staged = std::move(s.staged);
  s.staged.clear();
  for (auto& file : staged) file.temporary.rename_to(file.target);  // throws: the rest removed
  s.created_directories.clear();                                    // keep them
  forget_created_directories();
}

std::size_t OutputTransaction::staged() const {
  auto& s = state();
  const std::scoped_lock lock(s.mutex);
  return s.staged.size();
}

bool output_transaction_open() {
  auto& s = state();
  const std::scoped_lock lock(s.mutex);
  return s.open;
}

void note_input(const fs::path& path) {
  struct stat info {};
  if (::stat(path.c_str(), &info) != 0) return;
  auto& s = state();
  const std::scoped_lock lock(s.mutex);
  if (!s.open) return;  // inputs of a command: only within its transaction
  for (const auto& input : s.inputs) {
    if (input.device == info.st_dev && input.inode == info.st_ino) return;
  }
  s.inputs.push_back(FileIdentity{info.st_dev, info.st_ino, path.string()});
}

void create_output_directories(const fs::path& path) {
  std::vector<fs::path> missing;
  std::error_code ec;
  for (fs::path p = path; !p.empty(); p = p.parent_path()) {
    if (fs::exists(fs::symlink_status(p, ec))) break;
    missing.push_back(p);
    if (p == p.parent_path()) break;
  }
  if (!fs::is_directory(path, ec) && missing.empty()) {
    throw std::runtime_error("cannot create directory '" + path.string() +
                             "': it exists and is not a directory");
  }
  for (auto it = missing.rbegin(); it != missing.rend(); ++it) {
    if (!fs::create_directory(*it, ec) && ec) {
      throw std::runtime_error("cannot create directory '" + it->string() + "': " + ec.message());
    }
    auto& s = state();
    const std::scoped_lock lock(s.mutex);
    if (s.open) {
      s.created_directories.push_back(*it);
      register_created_directory(*it);
    }
  }
}

// ---- streaming outputs and scratch files -----------------------------------
namespace {

constexpr std::size_t kStreamBuffer = 1 << 20;

void write_all(int fd, const char* data, std::size_t length, const fs::path& name) {
  while (length > 0) {
    const ssize_t n = ::write(fd, data, length);
    if (n < 0 && errno == EINTR) continue;
    if (n <= 0) refuse(name, std::string("write failed: ") + std::strerror(errno));
    data += n;
    length -= static_cast<std::size_t>(n);
  }
}

void pwrite_all(int fd, const char* data, std::size_t length, std::uint64_t offset,
                const fs::path& name) {
  while (length > 0) {
    const ssize_t n = ::pwrite(fd, data, length, static_cast<off_t>(offset));
    if (n < 0 && errno == EINTR) continue;
    if (n <= 0) refuse(name, std::string("write failed: ") + std::strerror(errno));
    data += n;
    length -= static_cast<std::size_t>(n);
    offset += static_cast<std::uint64_t>(n);
  }
}

int open_temporary(const fs::path& temporary, const fs::path& name) {
  const int fd = ::open(temporary.c_str(), O_RDWR | O_CREAT | O_EXCL | O_CLOEXEC, 0666);
  if (fd < 0) refuse(name, std::strerror(errno));
  return fd;
}

}  // namespace

StreamingOutput::StreamingOutput(fs::path target) : target_(std::move(target)) {
  check_target(target_);
  temporary_ = temporary_path_for(target_);
  slot_ = register_temporary(temporary_);
  try {
    fd_ = open_temporary(temporary_, target_);
  } catch (...) {
    unregister_temporary(std::exchange(slot_, kSignalSlots));
    throw;
  }
}

StreamingOutput::StreamingOutput(StreamingOutput&& other) noexcept
    : target_(std::move(other.target_)),
      temporary_(std::move(other.temporary_)),
      slot_(std::exchange(other.slot_, kSignalSlots)),
      fd_(std::exchange(other.fd_, -1)),
      size_(other.size_),
      buffer_(std::move(other.buffer_)) {}

StreamingOutput& StreamingOutput::operator=(StreamingOutput&& other) noexcept {
  if (this != &other) {
    this->~StreamingOutput();
    new (this) StreamingOutput(std::move(other));
  }
  return *this;
}

StreamingOutput::~StreamingOutput() {
  if (fd_ >= 0) {
    ::close(fd_);
    ::unlink(temporary_.c_str());
  }
  unregister_temporary(std::exchange(slot_, kSignalSlots));
}

void StreamingOutput::flush() {
  if (buffer_.empty()) return;
  write_all(fd_, buffer_.data(), buffer_.size(), target_);
  buffer_.clear();
}

void StreamingOutput::append(std::string_view bytes) {
  if (fd_ < 0) throw std::logic_error("StreamingOutput: append after commit");
  size_ += bytes.size();
  if (buffer_.size() + bytes.size() > kStreamBuffer) {
    flush();
    if (bytes.size() > kStreamBuffer) {
      write_all(fd_, bytes.data(), bytes.size(), target_);
      return;
    }
  }
  buffer_.append(bytes);
}

void StreamingOutput::write_at(std::uint64_t offset, std::string_view bytes) {
  if (offset + bytes.size() > size_) throw std::logic_error("StreamingOutput: write past the end");
  flush();
  pwrite_all(fd_, bytes.data(), bytes.size(), offset, target_);
}

void StreamingOutput::append_from(int from_fd, std::uint64_t offset, std::uint64_t length) {
  flush();
  std::string chunk(std::min<std::uint64_t>(length, kStreamBuffer), '\0');
  while (length > 0) {
    const std::size_t want =
        static_cast<std::size_t>(std::min<std::uint64_t>(length, chunk.size()));
    const ssize_t n = ::pread(from_fd, chunk.data(), want, static_cast<off_t>(offset));
    if (n < 0 && errno == EINTR) continue;
    if (n <= 0) refuse(target_, "reading back a working file failed");
    write_all(fd_, chunk.data(), static_cast<std::size_t>(n), target_);
    offset += static_cast<std::uint64_t>(n);
    length -= static_cast<std::uint64_t>(n);
    size_ += static_cast<std::uint64_t>(n);
  }
}

void StreamingOutput::commit() {
  if (fd_ < 0) throw std::logic_error("StreamingOutput: committed twice");
  flush();
  if (::close(std::exchange(fd_, -1)) != 0) refuse(target_, "close failed");
  // From here the Temporary owns the file (removed on failure or rollback).
  unregister_temporary(std::exchange(slot_, kSignalSlots));
  Temporary temporary(temporary_);
  check_target(target_);
  stage_or_rename(std::move(temporary), target_);
}

ScratchFile::ScratchFile(const fs::path& near) {
  path_ = temporary_path_for(near.parent_path() / (near.filename().string() + ".work"));
  fd_ = open_temporary(path_, path_);
  ::unlink(path_.c_str());  // nameless from now on: gone with the process, whatever ends it
}

ScratchFile::~ScratchFile() {
  if (fd_ >= 0) ::close(fd_);
}

void ScratchFile::flush() {
  if (buffer_.empty()) return;
  pwrite_all(fd_, buffer_.data(), buffer_.size(), size_ - buffer_.size(), path_);
  buffer_.clear();
}

void ScratchFile::append(std::string_view bytes) {
  if (buffer_.size() + bytes.size() > kStreamBuffer) {
    const std::uint64_t end = size_;
    flush();
    if (bytes.size() > kStreamBuffer) {
      pwrite_all(fd_, bytes.data(), bytes.size(), end, path_);
      size_ += bytes.size();
      return;
    }
  }
  buffer_.append(bytes);
  size_ += bytes.size();
}

void ScratchFile::read(std::uint64_t offset, std::size_t length, void* out) {
  flush();
  auto* to = static_cast<char*>(out);
  while (length > 0) {
    const ssize_t n = ::pread(fd_, to, length, static_cast<off_t>(offset));
    if (n < 0 && errno == EINTR) continue;
    if (n <= 0) refuse(path_, "reading back a working file failed");
    to += n;
    offset += static_cast<std::uint64_t>(n);
    length -= static_cast<std::size_t>(n);
  }
}

int ScratchFile::fd() {
  flush();
  return fd_;
}

}  // namespace tofkit::io
