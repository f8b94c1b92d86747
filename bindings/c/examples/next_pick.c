/* A C cell controller asking a running psgrasp pipeline for picks.
 *
 *   cc -std=c11 -I bindings/c/include bindings/c/examples/next_pick.c \
 *      -L target/release -lpsgrasp_c -Wl,-rpath,$PWD/target/release -o next_pick
 *   ./next_pick config/default.toml            # the pick to try now
 *   ./next_pick config/default.toml failed     # it failed: the next one
 *   ./next_pick config/default.toml picked     # it worked: a newer frame's best
 *
 * Prints the pick in the robot base frame (TCP and flange), whether it is a fallback pick and its
 * pad fill, and the pipeline's health. */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "psgrasp.h"

static void print_pose(const char *name, const psgrasp_pose *p) {
    printf("%s %.9g %.9g %.9g %.9g %.9g %.9g %.9g\n", name, p->position_m[0], p->position_m[1],
           p->position_m[2], p->orientation_xyzw[0], p->orientation_xyzw[1],
           p->orientation_xyzw[2], p->orientation_xyzw[3]);
}

int main(int argc, char **argv) {
    if (argc < 2) {
        fprintf(stderr, "usage: %s PIPELINE_CONFIG [current|failed|picked] [TIMEOUT_MS]\n", argv[0]);
        return 2;
    }
    const char *what = argc > 2 ? argv[2] : "current";
    uint32_t timeout_ms = argc > 3 ? (uint32_t)strtoul(argv[3], NULL, 10) : 5000;

    psgrasp_client *client = psgrasp_connect_config(argv[1]);
    if (client == NULL) {
        fprintf(stderr, "connect: %s\n", psgrasp_last_error());
        return 1;
    }
    psgrasp_pick pick;
    psgrasp_result r;
    if (strcmp(what, "failed") == 0) {
        r = psgrasp_report_pick(client, PSGRASP_PICK_FAILED, timeout_ms, &pick);
    } else if (strcmp(what, "picked") == 0) {
        r = psgrasp_report_pick(client, PSGRASP_PICK_SUCCEEDED, timeout_ms, &pick);
    } else {
        r = psgrasp_next_pick(client, timeout_ms, &pick);
    }
    int rc = 0;
    if (r == PSGRASP_OK) {
        printf("frame_id %llu rank %u calibrated %u width_m %.9g quality %.9g\n",
               (unsigned long long)pick.frame_id, pick.rank, pick.base_calibrated, pick.width_m,
               pick.quality);
        print_pose("tcp", &pick.tcp);
        print_pose("pregrasp_tcp", &pick.pregrasp_tcp);
        print_pose("flange", &pick.flange);
        print_pose("workspace_tcp", &pick.workspace_tcp);
        psgrasp_pick_details details;
        if (psgrasp_last_pick_details(client, &details) == PSGRASP_OK) {
            printf("details fallback %u pad_fill_measured %u pad_fill %.9g\n", details.fallback,
                   details.pad_fill_measured, details.pad_fill);
        }
    } else {
        printf("no pick: result %d (%s)\n", (int)r, psgrasp_last_error());
        rc = 3;
    }
    psgrasp_status status;
    if (psgrasp_get_status(client, &status) == PSGRASP_OK) {
        printf("healthy %u workers_up %u frames_ok %llu\n", status.healthy, status.workers_up,
               (unsigned long long)status.frames_ok);
    }
    psgrasp_disconnect(client);
    return rc;
}
