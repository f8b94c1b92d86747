// A C++ cell controller asking a running psgrasp pipeline for picks, through a small RAII
// wrapper around the C API (psgrasp.h).
//
//   c++ -std=c++17 -I bindings/c/include bindings/c/examples/next_pick.cpp
//       -L target/release -lpsgrasp_c -Wl,-rpath,$PWD/target/release -o next_pick_cpp
//   (one command line)
//   ./next_pick_cpp config/default.toml [current|failed|picked] [TIMEOUT_MS]
#include <chrono>
#include <cstdio>
#include <optional>
#include <stdexcept>
#include <string>

#include "psgrasp.h"

namespace psgrasp {

/// One connection to a pipeline; use it from the thread that created it.
class Client {
  public:
    explicit Client(const std::string &config_path)
        : client_(psgrasp_connect_config(config_path.c_str())) {
        if (client_ == nullptr) throw std::runtime_error(psgrasp_last_error());
    }
    ~Client() { psgrasp_disconnect(client_); }
    Client(const Client &) = delete;
    Client &operator=(const Client &) = delete;

    /// The pick to try now, or nothing within `timeout` (`result()` says why).
    std::optional<psgrasp_pick> next_pick(std::chrono::milliseconds timeout) {
        psgrasp_pick pick{};
        return answer(psgrasp_next_pick(client_, wait(timeout), &pick), pick);
    }

    /// Reports the last pick and returns the next one.
    std::optional<psgrasp_pick> report(bool succeeded, std::chrono::milliseconds timeout) {
        psgrasp_pick pick{};
        return answer(psgrasp_report_pick(client_, succeeded ? PSGRASP_PICK_SUCCEEDED
                                                             : PSGRASP_PICK_FAILED,
                                          wait(timeout), &pick),
                      pick);
    }

    /// Whether the last pick is a fallback pick, and its pad fill.
    psgrasp_pick_details details() {
        psgrasp_pick_details d{};
        if (psgrasp_last_pick_details(client_, &d) != PSGRASP_OK) throw std::runtime_error(psgrasp_last_error());
        return d;
    }

    psgrasp_status status() {
        psgrasp_status s{};
        if (psgrasp_get_status(client_, &s) != PSGRASP_OK) throw std::runtime_error(psgrasp_last_error());
        return s;
    }

    psgrasp_result result() const { return last_; }

  private:
    static uint32_t wait(std::chrono::milliseconds t) { return static_cast<uint32_t>(t.count()); }

    std::optional<psgrasp_pick> answer(psgrasp_result r, const psgrasp_pick &pick) {
        last_ = r;
        if (r == PSGRASP_OK) return pick;
        if (r == PSGRASP_ERROR || r == PSGRASP_INVALID_ARGUMENT || r == PSGRASP_WRONG_THREAD)
            throw std::runtime_error(psgrasp_last_error());
        return std::nullopt;
    }

    psgrasp_client *client_;
    psgrasp_result last_ = PSGRASP_OK;
};

}  // namespace psgrasp

static void print_pose(const char *name, const psgrasp_pose &p) {
    std::printf("%s %.9g %.9g %.9g %.9g %.9g %.9g %.9g\n", name, p.position_m[0], p.position_m[1],
                p.position_m[2], p.orientation_xyzw[0], p.orientation_xyzw[1], p.orientation_xyzw[2],
                p.orientation_xyzw[3]);
}

int main(int argc, char **argv) {
    if (argc < 2) {
        std::fprintf(stderr, "usage: %s PIPELINE_CONFIG [current|failed|picked] [TIMEOUT_MS]\n", argv[0]);
        return 2;
    }
    const std::string what = argc > 2 ? argv[2] : "current";
    const std::chrono::milliseconds timeout(argc > 3 ? std::stoul(argv[3]) : 5000);
    try {
        psgrasp::Client client(argv[1]);
        std::optional<psgrasp_pick> pick;
        if (what == "failed") pick = client.report(false, timeout);
        else if (what == "picked") pick = client.report(true, timeout);
        else pick = client.next_pick(timeout);
        int rc = 0;
        if (pick) {
            std::printf("frame_id %llu rank %u calibrated %u width_m %.9g quality %.9g\n",
                        static_cast<unsigned long long>(pick->frame_id), pick->rank,
                        pick->base_calibrated, pick->width_m, pick->quality);
            print_pose("tcp", pick->tcp);
            print_pose("pregrasp_tcp", pick->pregrasp_tcp);
            print_pose("flange", pick->flange);
            print_pose("workspace_tcp", pick->workspace_tcp);
            const psgrasp_pick_details d = client.details();
            std::printf("details fallback %u pad_fill_measured %u pad_fill %.9g\n", d.fallback,
                        d.pad_fill_measured, d.pad_fill);
        } else {
            std::printf("no pick: result %d (%s)\n", static_cast<int>(client.result()), psgrasp_last_error());
            rc = 3;
        }
        const psgrasp_status s = client.status();
        std::printf("healthy %u workers_up %u frames_ok %llu\n", s.healthy, s.workers_up,
                    static_cast<unsigned long long>(s.frames_ok));
        return rc;
    } catch (const std::exception &e) {
        std::fprintf(stderr, "psgrasp: %s\n", e.what());
        return 1;
    }
}
