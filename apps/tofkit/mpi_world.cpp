#include "mpi_world.hpp"

#include <unistd.h>

#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <map>
#include <stdexcept>
#include <string>
#include <vector>

#if defined(TOFKIT_HAVE_MPI)
#include <mpi.h>
#endif

namespace tofkit::app {
namespace {

// Started by mpirun (Open MPI) or srun (Slurm's PMI/PMIx)?
bool under_launcher() {
  for (const char* name : {"OMPI_COMM_WORLD_SIZE", "PMI_SIZE", "PMIX_RANK"}) {
    if (std::getenv(name) != nullptr) return true;
  }
  return false;
}

bool g_done = false;

// TOFKIT_MPI_PROFILE=1: each rank's time making chunks, handing chunks to
// `take` (rank 0: correcting and writing), and waiting, on stderr at the end.
struct Profile {
  bool on = std::getenv("TOFKIT_MPI_PROFILE") != nullptr;
  double make_s = 0, take_s = 0, idle_s = 0;
  std::size_t made = 0;
};
Profile g_profile;
double now_s() {
  return std::chrono::duration<double>(std::chrono::steady_clock::now().time_since_epoch()).count();
}
// Runs `f`, adding its time to `seconds` when profiling.
template <class F>
void timed(double& seconds, F&& f) {
  if (!g_profile.on) return f();
  const double t0 = now_s();
  f();
  seconds += now_s() - t0;
}
void nap() {
  timed(g_profile.idle_s, [] { ::usleep(100); });
}

}  // namespace

#if defined(TOFKIT_HAVE_MPI)

namespace {

void finalize_at_exit() {
  int finalized = 0;
  MPI_Finalized(&finalized);
  // Only after success: a rank that failed must not wait for its peers in
  // MPI_Finalize; exiting without it makes the launcher end the job.
  if (g_done && !finalized) MPI_Finalize();
}

void check(int code, const char* what) {
  if (code != MPI_SUCCESS) throw std::runtime_error(std::string("MPI: ") + what + " failed");
}

constexpr int kChunkTag = 33;    // a made chunk: its index (8 bytes), then its bytes
constexpr int kRequestTag = 34;  // a rank asks for a chunk to make
constexpr int kAssignTag = 35;   // rank 0's answer: a chunk index, or kNoMore

constexpr long long kNoMore = -1;

// Waiting without spinning: a rank that waits gives its core to the others
// (MPI's blocking calls poll at full speed, which on a shared or
// oversubscribed node slows the rank being waited for).
void wait_politely(MPI_Request& request) {
  for (int done = 0;;) {
    check(MPI_Test(&request, &done, MPI_STATUS_IGNORE), "MPI_Test");
    if (done) return;
    nap();
  }
}

// The send on its way (ranks other than 0): advanced by mpi_progress while
// the next chunk is made (a large message moves only while both sides are in
// MPI calls when the transport cannot read the sender's memory directly).
MPI_Request g_pending = MPI_REQUEST_NULL;

// Rank 0's side of mpi_ordered_chunks. The chunks are handed out as the
// ranks ask for them (rank 0 takes one itself whenever it is free), so a rank
// slowed by its node's other work, or by heavier chunks, makes fewer: a fixed
// round-robin left every rank waiting for the slowest, and rank 0, which also
// writes, was the slowest. Chunks are handed out at most `window` ahead of the
// next one to write, which bounds rank 0's held chunks (memory).
class Dispatcher {
 public:
  Dispatcher(std::size_t chunks, int size,
             const std::function<void(std::size_t, std::string_view)>& take)
      : chunks_(chunks),
        window_(2 * static_cast<std::size_t>(size)),
        waiting_(static_cast<std::size_t>(size), false),
        told_done_(static_cast<std::size_t>(size), false),
        take_(take) {}

  // Answers requests and receives finished chunks (also called from
  // mpi_progress while rank 0 makes a chunk of its own).
  void serve() {
    for (int arrived = 1; arrived;) {
      MPI_Status status;
      check(MPI_Iprobe(MPI_ANY_SOURCE, kChunkTag, MPI_COMM_WORLD, &arrived, &status), "MPI_Iprobe");
      if (!arrived) break;
      int count = 0;
      MPI_Get_count(&status, MPI_BYTE, &count);
      std::string bytes = spare();
      bytes.resize(static_cast<std::size_t>(count));
      check(MPI_Recv(bytes.data(), count, MPI_BYTE, status.MPI_SOURCE, kChunkTag, MPI_COMM_WORLD,
                     MPI_STATUS_IGNORE),
            "MPI_Recv");
      long long chunk = 0;
      if (bytes.size() < sizeof chunk) throw std::runtime_error("MPI: a chunk without its index");
      std::memcpy(&chunk, bytes.data(), sizeof chunk);
      held_.emplace(static_cast<std::size_t>(chunk), Held{std::move(bytes), sizeof chunk});
    }
    for (int arrived = 1; arrived;) {
      MPI_Status status;
      check(MPI_Iprobe(MPI_ANY_SOURCE, kRequestTag, MPI_COMM_WORLD, &arrived, &status),
            "MPI_Iprobe");
      if (!arrived) break;
      char none = 0;
      check(MPI_Recv(&none, 1, MPI_BYTE, status.MPI_SOURCE, kRequestTag, MPI_COMM_WORLD,
                     MPI_STATUS_IGNORE),
            "MPI_Recv");
      waiting_[static_cast<std::size_t>(status.MPI_SOURCE)] = true;
    }
    for (std::size_t r = 1; r < waiting_.size(); ++r) {
      if (!waiting_[r]) continue;
      long long answer = kNoMore;
      if (next_ < chunks_) {
        if (!may_hand_out()) continue;  // asked again once rank 0 has written
        answer = static_cast<long long>(next_++);
      } else {
        told_done_[r] = true;
      }
      // (8 bytes: sent eagerly, the call returns at once.)
      check(MPI_Send(&answer, 1, MPI_LONG_LONG, static_cast<int>(r), kAssignTag, MPI_COMM_WORLD),
            "MPI_Send");
      waiting_[r] = false;
    }
  }

  void run(const std::function<void(std::size_t, std::string&)>& make) {
    while (written_ < chunks_) {
      serve();
      write_held();
      if (written_ >= chunks_) break;
      if (next_ < chunks_ && may_hand_out()) {
        const std::size_t c = next_++;
        std::string bytes = spare();
        timed(g_profile.make_s, [&] { make(c, bytes); });
        ++g_profile.made;
        held_.emplace(c, Held{std::move(bytes), 0});
        continue;
      }
      nap();
    }
    // Every other rank's last request: no more chunks.
    for (;;) {
      bool all = true;
      for (std::size_t r = 1; r < told_done_.size(); ++r) all = all && told_done_[r];
      if (all) return;
      serve();
      nap();
    }
  }

 private:
  [[nodiscard]] bool may_hand_out() const { return next_ < written_ + window_; }
  // An empty buffer, with the capacity of a written chunk's when there is one.
  std::string spare() {
    if (spare_.empty()) return {};
    std::string bytes = std::move(spare_.back());
    spare_.pop_back();
    bytes.clear();
    return bytes;
  }
  void write_held() {
    for (auto it = held_.find(written_); it != held_.end(); it = held_.find(written_)) {
      if (take_)
        timed(g_profile.take_s, [&] {
          take_(written_, std::string_view(it->second.bytes).substr(it->second.offset));
        });
      spare_.push_back(std::move(it->second.bytes));
      held_.erase(it);
      ++written_;
    }
  }

  std::size_t chunks_, window_;
  std::size_t next_ = 0, written_ = 0;  // the next chunk to hand out, to write
  std::vector<bool> waiting_, told_done_;
  struct Held {
    std::string bytes;
    std::size_t offset;  // where the chunk's bytes start (after a received chunk's index)
  };
  std::map<std::size_t, Held> held_;
  std::vector<std::string> spare_;  // written chunks' buffers, for the next ones
  const std::function<void(std::size_t, std::string_view)>& take_;
};

Dispatcher* g_dispatcher = nullptr;  // rank 0, inside mpi_ordered_chunks

}  // namespace

MpiWorld mpi_world() {
  static const MpiWorld world = [] {
    MpiWorld w;
    if (!under_launcher()) return w;
    // Every rank on this node (Open MPI's local size is its world size):
    // messages go through shared memory, by Open MPI's own ob1 layer unless
    // told otherwise; the UCX layer it would pick first takes 0.2 s of
    // MPI_Init per job for no gain here (0.24 -> 0.04 s measured). A pml
    // chosen with --mca or in the environment is kept.
    const char* local = std::getenv("OMPI_COMM_WORLD_LOCAL_SIZE");
    const char* world_size = std::getenv("OMPI_COMM_WORLD_SIZE");
    if (local != nullptr && world_size != nullptr && std::string(local) == world_size)
      ::setenv("OMPI_MCA_pml", "ob1", /*overwrite=*/0);
    int provided = 0;
    check(MPI_Init_thread(nullptr, nullptr, MPI_THREAD_FUNNELED, &provided), "MPI_Init_thread");
    std::atexit(finalize_at_exit);
    MPI_Comm_rank(MPI_COMM_WORLD, &w.rank);
    MPI_Comm_size(MPI_COMM_WORLD, &w.size);
    return w;
  }();
  return world;
}

void mpi_done() {
  g_done = true;
  if (g_profile.on && mpi_world().size > 1)
    std::fprintf(
        stderr, "tofkit mpi: rank %d made %zu chunks in %.3f s, took in %.3f s, waited %.3f s\n",
        mpi_world().rank, g_profile.made, g_profile.make_s, g_profile.take_s, g_profile.idle_s);
}

void mpi_ordered_chunks(std::size_t chunks,
                        const std::function<void(std::size_t, std::string&)>& make,
                        const std::function<void(std::size_t, std::string_view)>& take) {
  const MpiWorld w = mpi_world();
  if (w.size == 1) {  // one process (no launcher): nothing to share
    std::string bytes;
    for (std::size_t c = 0; c < chunks; ++c) {
      bytes.clear();
      make(c, bytes);
      if (take) take(c, bytes);
    }
    return;
  }
  if (w.rank == 0) {
    Dispatcher dispatcher(chunks, w.size, take);
    g_dispatcher = &dispatcher;
    try {
      dispatcher.run(make);
    } catch (...) {
      g_dispatcher = nullptr;
      throw;
    }
    g_dispatcher = nullptr;
    return;
  }
  // The other ranks: ask for a chunk, and for the next one before making it
  // (its answer comes meanwhile: no wait for rank 0 between chunks), make
  // it, send it (its index first); two buffers, one being sent while the
  // next chunk is made in the other.
  std::string buffers[2];
  int next = 0;
  MPI_Request& request = g_pending;
  long long asked = kNoMore;
  MPI_Request answer = MPI_REQUEST_NULL;
  const auto ask = [&] {
    char none = 0;
    check(MPI_Send(&none, 1, MPI_BYTE, 0, kRequestTag, MPI_COMM_WORLD), "MPI_Send");
    check(MPI_Irecv(&asked, 1, MPI_LONG_LONG, 0, kAssignTag, MPI_COMM_WORLD, &answer), "MPI_Irecv");
  };
  const auto answered = [&] {
    for (int done = 0;;) {  // (the last send advances meanwhile)
      check(MPI_Test(&answer, &done, MPI_STATUS_IGNORE), "MPI_Test");
      if (done) return asked;
      mpi_progress();
      nap();
    }
  };
  ask();
  for (long long chunk = answered(); chunk != kNoMore;) {
    ask();
    std::string& bytes = buffers[next];
    next ^= 1;
    bytes.assign(reinterpret_cast<const char*>(&chunk), sizeof chunk);
    timed(g_profile.make_s, [&] { make(static_cast<std::size_t>(chunk), bytes); });
    ++g_profile.made;
    wait_politely(request);  // (the other buffer's send)
    check(MPI_Isend(bytes.data(), static_cast<int>(bytes.size()), MPI_BYTE, 0, kChunkTag,
                    MPI_COMM_WORLD, &request),
          "MPI_Isend");
    chunk = answered();
  }
  wait_politely(request);
}

void mpi_progress() {
  if (g_dispatcher != nullptr) {
    g_dispatcher->serve();
    return;
  }
  if (g_pending == MPI_REQUEST_NULL) return;
  int done = 0;
  MPI_Test(&g_pending, &done, MPI_STATUS_IGNORE);
}

void mpi_broadcast(std::string& bytes) {
  // Non-blocking, waited for politely: the other ranks may wait here while
  // rank 0 works (a factory calibration being made) on a shared core.
  unsigned long long size = bytes.size();
  MPI_Request request = MPI_REQUEST_NULL;
  check(MPI_Ibcast(&size, 1, MPI_UNSIGNED_LONG_LONG, 0, MPI_COMM_WORLD, &request), "MPI_Ibcast");
  wait_politely(request);
  bytes.resize(size);
  check(MPI_Ibcast(bytes.data(), static_cast<int>(size), MPI_BYTE, 0, MPI_COMM_WORLD, &request),
        "MPI_Ibcast");
  wait_politely(request);
}

#else

MpiWorld mpi_world() {
  const char* size = std::getenv("OMPI_COMM_WORLD_SIZE");
  if (size == nullptr) size = std::getenv("PMI_SIZE");
  if (under_launcher() && size != nullptr && std::string(size) != "1") {
    throw std::runtime_error(
        "started by mpirun, but this tofkit was built without MPI (install libopenmpi-dev and "
        "rebuild): each rank would write the whole output");
  }
  return {};
}

void mpi_done() {
  g_done = true;
}

void mpi_ordered_chunks(std::size_t chunks,
                        const std::function<void(std::size_t, std::string&)>& make,
                        const std::function<void(std::size_t, std::string_view)>& take) {
  std::string bytes;
  for (std::size_t c = 0; c < chunks; ++c) {
    bytes.clear();
    make(c, bytes);
    if (take) take(c, bytes);
  }
}

void mpi_broadcast(std::string&) {}

void mpi_progress() {}

#endif

}  // namespace tofkit::app
