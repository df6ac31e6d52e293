#pragma once
/// \file Running the `tofkit` binary (TOFKIT_BINARY) from a test and reading
/// back what it printed: one helper for every end-to-end CLI test, and a
/// fixture giving each test a fresh working directory.

#include <gtest/gtest.h>
#include <sys/stat.h>
#include <sys/wait.h>
#include <unistd.h>

#include <atomic>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <functional>
#include <map>
#include <optional>
#include <sstream>
#include <string>
#include <utility>
#include <vector>

namespace tofkit::test {

/// Sets an environment variable for a scope, restoring it after.
class ScopedEnv {
 public:
  ScopedEnv(const char* name, const char* value) : name_(name) {
    if (const char* old = std::getenv(name)) old_ = old;
    if (value == nullptr) {
      ::unsetenv(name);
    } else {
      ::setenv(name, value, 1);
    }
  }
  ~ScopedEnv() {
    if (old_) {
      ::setenv(name_.c_str(), old_->c_str(), 1);
    } else {
      ::unsetenv(name_.c_str());
    }
  }
  ScopedEnv(const ScopedEnv&) = delete;
  ScopedEnv& operator=(const ScopedEnv&) = delete;

 private:
  std::string name_;
  std::optional<std::string> old_;
};

/// What a run of the binary left: exit status (-signal when killed by one),
/// stdout and stderr.
struct CliResult {
  int status = -1;
  std::string out;
  std::string err;
};

/// The whole of a file ("" if it cannot be read).
inline std::string read_file(const std::filesystem::path& file) {
  std::ifstream in(file, std::ios::binary);
  std::ostringstream s;
  s << in.rdbuf();
  return s.str();
}

/// An empty directory `<prefix><name>_<pid>` under the system's temporary one
/// (emptied if a previous run left it).
inline std::filesystem::path fresh_dir(const std::string& prefix, const std::string& name) {
  const std::filesystem::path dir =
      std::filesystem::temp_directory_path() / (prefix + name + "_" + std::to_string(::getpid()));
  std::filesystem::remove_all(dir);
  std::filesystem::create_directories(dir);
  return dir;
}

/// `tofkit <args>` through the shell with working directory `dir`, stdout
/// redirected to `out` and stderr to `err` (relative paths are in `dir`), both
/// read back afterwards.
inline CliResult run_tofkit(const std::filesystem::path& dir, const std::string& args,
                            const std::filesystem::path& out, const std::filesystem::path& err) {
  const std::string command = "cd '" + dir.string() + "' && '" TOFKIT_BINARY "' " + args + " >'" +
                              out.string() + "' 2>'" + err.string() + "'";
  const int raw = std::system(command.c_str());
  CliResult r;
  r.status = WIFEXITED(raw) ? WEXITSTATUS(raw) : WIFSIGNALED(raw) ? -WTERMSIG(raw) : -1;
  r.out = read_file(out.is_absolute() ? out : dir / out);
  r.err = read_file(err.is_absolute() ? err : dir / err);
  return r;
}

/// A test with its own empty directory under the system's temporary one
/// (`prefix` + process id + a counter), removed afterwards.
class CliFixture : public ::testing::Test {
 protected:
  explicit CliFixture(std::string prefix) : prefix_(std::move(prefix)) {}

  void SetUp() override {
    static std::atomic<int> counter{0};
    dir_ = std::filesystem::temp_directory_path() /
           (prefix_ + std::to_string(::getpid()) + "_" + std::to_string(counter++));
    std::filesystem::create_directories(dir_);
  }
  void TearDown() override {
    std::error_code ec;
    std::filesystem::remove_all(dir_, ec);
  }

  /// `tofkit <args>` in the test's directory; stdout to `out` (a file there),
  /// stderr to stderr.txt.
  CliResult run(const std::string& args, const std::string& out = "stdout.txt") const {
    return run_tofkit(dir_, args, out, "stderr.txt");
  }
  [[nodiscard]] std::string read(const std::string& name) const { return read_file(dir_ / name); }
  void write(const std::string& name, const std::string& text) const {
    std::ofstream(dir_ / name, std::ios::binary) << text;
  }
  [[nodiscard]] std::string path(const std::string& name) const { return (dir_ / name).string(); }

  std::filesystem::path dir_;

 private:
  std::string prefix_;
};

/// A fixture for bad input: a refused command must exit 1 with a message that
/// names what was wrong, and leave the directory under test as it was.
class RefusalFixture : public CliFixture {
 protected:
  using CliFixture::CliFixture;

  /// Stdout discarded; stderr outside the directory under test.
  CliResult run(const std::string& args) const {
    return run_tofkit(dir_, args, "/dev/null", scratch() / "stderr.txt");
  }

  std::filesystem::path scratch() const {
    std::filesystem::path p = dir_;
    p += "_scratch";
    std::filesystem::create_directories(p);
    return p;
  }

  /// Every entry (hidden ones too): its type, and for files size, mtime and a
  /// hash of the content. (A directory's own mtime changes when a temporary
  /// comes and goes; its entries are what must stay the same.)
  std::map<std::string, std::string> snapshot() const {
    std::map<std::string, std::string> entries;
    for (const auto& e : std::filesystem::recursive_directory_iterator(dir_)) {
      struct stat info {};
      ::lstat(e.path().c_str(), &info);
      std::string state = std::to_string(info.st_mode);
      if (S_ISREG(info.st_mode)) {
        state += " " + std::to_string(info.st_size) + " " + std::to_string(info.st_mtim.tv_sec) +
                 "." + std::to_string(info.st_mtim.tv_nsec) + " " +
                 std::to_string(std::hash<std::string>{}(read_file(e.path())));
      }
      entries[std::filesystem::relative(e.path(), dir_).string()] = state;
    }
    return entries;
  }

  /// Status 1, a message with every needle, the directory untouched.
  void expect_refused(const std::string& args, const std::vector<std::string>& needles) const {
    const auto before = snapshot();
    const CliResult r = run(args);
    EXPECT_EQ(r.status, 1) << args << "\n" << r.err;
    EXPECT_NE(r.err.find("error: "), std::string::npos) << args << "\n" << r.err;
    for (const auto& needle : needles) {
      EXPECT_NE(r.err.find(needle), std::string::npos)
          << args << "\nmessage lacks '" << needle << "':\n"
          << r.err;
    }
    EXPECT_EQ(snapshot(), before) << args << ": the directory changed";
  }
};

}  // namespace tofkit::test
