#include "tofkit/io/byte_source.hpp"

#include <fcntl.h>
#include <poll.h>
#include <sys/ioctl.h>
#include <sys/stat.h>
#include <termios.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <cstdlib>
#include <cstring>
#include <stdexcept>

namespace tofkit::io {
namespace {

std::runtime_error system_error(const std::string& what) {
  return std::runtime_error(what + ": " + std::strerror(errno));
}

speed_t speed_constant(int baud, const std::string& name) {
  switch (baud) {
    case 9600:
      return B9600;
    case 19200:
      return B19200;
    case 38400:
      return B38400;
    case 57600:
      return B57600;
    case 115200:
      return B115200;
    case 230400:
      return B230400;
    case 460800:
      return B460800;
    case 500000:
      return B500000;
    case 576000:
      return B576000;
    case 921600:
      return B921600;
    case 1000000:
      return B1000000;
    case 1152000:
      return B1152000;
    case 1500000:
      return B1500000;
    case 2000000:
      return B2000000;
    case 2500000:
      return B2500000;
    case 3000000:
      return B3000000;
    case 3500000:
      return B3500000;
    case 4000000:
      return B4000000;
    default:
      break;
  }
  throw std::runtime_error(name + ": --baud " + std::to_string(baud) +
                           " is not a standard rate (9600 ... 4000000)");
}

}  // namespace

void configure_raw_terminal(int fd, int baud, const std::string& name) {
  termios tio{};
  if (tcgetattr(fd, &tio) != 0) throw system_error(name + ": tcgetattr");
  cfmakeraw(&tio);
  tio.c_cflag |= CLOCAL | CREAD;
  tio.c_cflag &= ~static_cast<tcflag_t>(CSTOPB | PARENB | CRTSCTS);
  tio.c_cc[VMIN] = 1;
  tio.c_cc[VTIME] = 0;
  if (baud > 0) {
    const speed_t speed = speed_constant(baud, name);
    cfsetispeed(&tio, speed);
    cfsetospeed(&tio, speed);
  }
  if (tcsetattr(fd, TCSANOW, &tio) != 0) throw system_error(name + ": tcsetattr");
}

ByteSource::ByteSource(const std::string& path, int baud) : path_(path) {
  if (path == "-") {
    fd_ = STDIN_FILENO;
  } else {
    fd_ = ::open(path.c_str(), O_RDONLY | O_NOCTTY | O_CLOEXEC);
    if (fd_ < 0) throw system_error(path);
    owned_ = true;
    struct stat st {};
    if (fstat(fd_, &st) == 0 && S_ISDIR(st.st_mode)) {
      ::close(fd_);
      throw std::runtime_error(path + ": is a directory");
    }
  }
  terminal_ = isatty(fd_) != 0;
  if (baud > 0 && !terminal_) {
    if (owned_) ::close(fd_);
    throw std::runtime_error(path + ": --baud given, but this is not a serial port or terminal");
  }
  if (terminal_) {
    try {
      termios saved{};
      if (tcgetattr(fd_, &saved) != 0) throw system_error(path + ": tcgetattr");
      configure_raw_terminal(fd_, baud, path);
      saved_ = std::make_unique<termios>(saved);
      if (path == "-") {
        // Stdin on a terminal is a person's keyboard: Ctrl-C must still end
        // the stream (SIGINT), not arrive as byte 0x03.
        termios tio{};
        if (tcgetattr(fd_, &tio) == 0) {
          tio.c_lflag |= ISIG;
          tcsetattr(fd_, TCSANOW, &tio);
        }
      }
    } catch (...) {
      restore_terminal();
      if (owned_) ::close(fd_);
      throw;
    }
  }
}

void ByteSource::restore_terminal() noexcept {
  if (saved_) tcsetattr(fd_, TCSANOW, saved_.get());
  saved_.reset();
}

ByteSource::~ByteSource() {
  restore_terminal();  // the terminal as it was found, on every way out
  if (owned_ && fd_ >= 0) ::close(fd_);
}

ByteSource::Status ByteSource::read(std::span<std::uint8_t> buffer, int timeout_ms,
                                    std::size_t& got) {
  got = 0;
  pollfd p{fd_, POLLIN, 0};
  const int ready = ::poll(&p, 1, timeout_ms);
  if (ready < 0) {
    if (errno == EINTR) return Status::kTimeout;
    throw system_error(path_ + ": poll");
  }
  if (ready == 0) return Status::kTimeout;
  const ssize_t n = ::read(fd_, buffer.data(), buffer.size());
  if (n > 0) {
    got = static_cast<std::size_t>(n);
    return Status::kData;
  }
  if (n == 0) return Status::kEnd;
  if (errno == EINTR || errno == EAGAIN) return Status::kTimeout;
  if (errno == EIO && terminal_) return Status::kEnd;  // the pty's master side closed
  throw system_error(path_ + ": read");
}

PseudoTerminal::PseudoTerminal() {
  master_ = posix_openpt(O_RDWR | O_NOCTTY | O_CLOEXEC);
  if (master_ < 0) throw system_error("posix_openpt");
  if (grantpt(master_) != 0 || unlockpt(master_) != 0) {
    ::close(master_);
    throw system_error("grantpt/unlockpt");
  }
  const char* name = ptsname(master_);
  if (name == nullptr) {
    ::close(master_);
    throw system_error("ptsname");
  }
  slave_path_ = name;
  slave_ = ::open(slave_path_.c_str(), O_RDWR | O_NOCTTY | O_CLOEXEC);
  if (slave_ < 0) {
    ::close(master_);
    throw system_error(slave_path_);
  }
  try {
    configure_raw_terminal(slave_, 0, slave_path_);
  } catch (...) {
    ::close(slave_);
    ::close(master_);
    throw;
  }
}

std::size_t PseudoTerminal::wait_drained(int timeout_ms) const {
  // Bytes pass from the master through a buffer to the slave's input queue, so
  // an empty queue counts only when it stays empty for 50 ms.
  int empty_checks = 0;
  for (int waited = 0;; waited += 10) {
    int unread = 0;
    if (ioctl(slave_, FIONREAD, &unread) != 0) return 0;
    empty_checks = unread <= 0 ? empty_checks + 1 : 0;
    if (empty_checks >= 5 || waited >= timeout_ms)
      return static_cast<std::size_t>(std::max(unread, 0));
    ::usleep(10'000);
  }
}

bool PseudoTerminal::wait_for_reader(const std::atomic<bool>& stop, int settle_ms) {
  // While no one holds the slave open the master reports POLLHUP; our own
  // descriptor is closed for the wait (the line's raw settings stay with the
  // pair) and opened again once a reader has come, for wait_drained.
  if (slave_ >= 0) ::close(slave_);
  slave_ = -1;
  for (;;) {
    if (stop) return false;
    pollfd p{master_, POLLOUT, 0};
    if (::poll(&p, 1, 10) > 0 && (p.revents & POLLHUP) == 0) break;
    if ((p.revents & POLLHUP) != 0) ::usleep(10'000);  // poll returns at once on a hang-up
  }
  slave_ = ::open(slave_path_.c_str(), O_RDWR | O_NOCTTY | O_CLOEXEC);
  if (slave_ < 0) throw system_error(slave_path_);
  for (int waited = 0; waited < settle_ms && !stop; waited += 10) ::usleep(10'000);
  return !stop;
}

void PseudoTerminal::linger(const std::atomic<bool>& stop, int linger_ms) {
  if (slave_ >= 0) ::close(slave_);  // our descriptor must not hold the line up
  slave_ = -1;
  for (int waited = 0; waited < linger_ms && !stop; waited += 10) {
    pollfd p{master_, POLLIN, 0};
    if (::poll(&p, 1, 0) > 0 && (p.revents & POLLHUP) != 0) return;  // the reader closed
    ::usleep(10'000);
  }
}

PseudoTerminal::~PseudoTerminal() {
  if (slave_ >= 0) ::close(slave_);
  if (master_ >= 0) ::close(master_);
}

void write_all(int fd, std::span<const std::uint8_t> bytes, const std::string& name,
               int timeout_ms) {
  std::size_t done = 0;
  while (done < bytes.size()) {
    if (timeout_ms >= 0) {
      pollfd p{fd, POLLOUT, 0};
      const int ready = ::poll(&p, 1, timeout_ms);
      if (ready < 0 && errno == EINTR) continue;
      if (ready == 0) {
        throw std::runtime_error(name + ": no reader took the bytes for " +
                                 std::to_string(timeout_ms / 1000) + " s");
      }
    }
    const ssize_t n = ::write(fd, bytes.data() + done, bytes.size() - done);
    if (n < 0) {
      if (errno == EINTR) continue;
      throw system_error(name + ": write");
    }
    done += static_cast<std::size_t>(n);
  }
}

}  // namespace tofkit::io
