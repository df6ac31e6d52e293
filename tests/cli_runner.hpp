#pragma once
/// \file Running the `tofkit` binary (TOFKIT_BINARY) from a test and reading
/// back what it printed: one helper for every end-to-end CLI test, and a
/// fixture giving each test a fresh working directory.

#include <gtest/gtest.h>
#include <sys/wait.h>
#include <unistd.h>

#include <atomic>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <string>
#include <utility>

namespace tofkit::test {

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

}  // namespace tofkit::test
