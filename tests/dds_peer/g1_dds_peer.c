/* An independent DDS peer for `g1fw run --dds`: Debian's CycloneDDS 0.10.2 (the robot's version),
 * this directory's own IDL compiled by idlc, and Unitree's CRC as unitree_sdk2 computes it (over
 * the C struct, 32-bit words, MSB first, poly 0x04C11DB7). None of the project's code is used.
 *
 * It stands between a simulator (the robot side, domain R) and the controller (domain C):
 *   rt/lowstate  robot --> peer --> controller   (CRC checked, recomputed by this peer)
 *   rt/lowcmd    robot <-- peer <-- controller   (CRC and gains checked, then forwarded)
 * and injects faults on the controller's side, at times counted in controller commands (2 ms each):
 *   stale@T+D    repeat the last state (same tick counter) instead of relaying new ones
 *   crc@T+D      relay states with a wrong CRC
 *   variant@T+D  relay states whose mode_machine names the dual-arm G1 (9: no legs)
 *   size@T+D     also publish 16-byte samples under LowState_'s type name on rt/lowstate
 *   writer@T     start a second rt/lowcmd writer on the controller's domain
 *   die@T        print the report and exit at once, without cleaning up (a crashed robot)
 *
 * usage: g1_dds_peer --robot-domain R --controller-domain C --gains FILE [--fault SPEC]...
 *                    [--idle-exit S] [--max-time S]
 * FILE: one line per enabled slot: slot startup_kp startup_kd policy_kp policy_kd damping_kd.
 * At the end it prints one JSON object on stdout.
 */
#include <math.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>
#include <unistd.h>

#include "dds/dds.h"
#include "short_state.h"
#include "unitree_hg.h"

typedef unitree_hg_msg_dds__LowCmd_ LowCmd;
typedef unitree_hg_msg_dds__LowState_ LowState;

#define NMOTORS 35
#define MAX_FAULTS 8

static uint32_t crc32_core(const uint32_t *p, size_t n) {
  uint32_t crc = 0xFFFFFFFFu;
  const uint32_t poly = 0x04C11DB7u;
  for (size_t i = 0; i < n; i++) {
    uint32_t data = p[i], xbit = 1u << 31;
    for (int j = 0; j < 32; j++) {
      if (crc & 0x80000000u)
        crc = (crc << 1) ^ poly;
      else
        crc <<= 1;
      if (data & xbit) crc ^= poly;
      xbit >>= 1;
    }
  }
  return crc;
}
#define CRC_OF(msg) crc32_core((const uint32_t *)&(msg), sizeof(msg) / 4 - 1)

struct fault {
  char kind[16];
  double start, dur;
  int fired;
};

struct gains {
  int enabled;
  float st_kp, st_kd, po_kp, po_kd, damp_kd;
};

static double now_s(void) {
  struct timespec ts;
  clock_gettime(CLOCK_MONOTONIC, &ts);
  return ts.tv_sec + ts.tv_nsec * 1e-9;
}

static void die_usage(const char *why) {
  fprintf(stderr, "g1_dds_peer: %s\n", why);
  exit(2);
}

static dds_entity_t check(dds_entity_t e, const char *what) {
  if (e < 0) {
    fprintf(stderr, "g1_dds_peer: %s: %s\n", what, dds_strretcode(-e));
    exit(2);
  }
  return e;
}

/* Counters for the report. */
static struct {
  long states_in, state_crc_bad_from_robot, states_out, short_out;
  long cmds, cmd_crc_ok, cmd_crc_bad, mode_machine_mismatch;
  long startup, policy, damping, mismatch;
  char first_mismatch[256];
  double t_end;
  const char *end;
} R;

static void report(const struct fault *f, int nf) {
  printf("{\"states_in\": %ld, \"state_crc_bad_from_robot\": %ld, \"states_out\": %ld, \"short_out\": %ld, "
         "\"cmds\": %ld, \"cmd_crc_ok\": %ld, \"cmd_crc_bad\": %ld, \"mode_machine_mismatch\": %ld, "
         "\"frames\": {\"startup\": %ld, \"policy\": %ld, \"damping\": %ld, \"mismatch\": %ld}, "
         "\"first_mismatch\": \"%s\", \"t_end\": %.3f, \"end\": \"%s\", \"faults_fired\": [",
         R.states_in, R.state_crc_bad_from_robot, R.states_out, R.short_out, R.cmds, R.cmd_crc_ok, R.cmd_crc_bad,
         R.mode_machine_mismatch, R.startup, R.policy, R.damping, R.mismatch, R.first_mismatch, R.t_end, R.end);
  int first = 1;
  for (int i = 0; i < nf; i++)
    if (f[i].fired) {
      printf("%s\"%s\"", first ? "" : ", ", f[i].kind);
      first = 0;
    }
  printf("]}\n");
  fflush(stdout);
}

/* Which phase's gains this command carries: every enabled slot must agree. */
static void classify(const LowCmd *c, const struct gains *g) {
  int all_st = 1, all_po = 1, all_damp = 1;
  for (int s = 0; s < NMOTORS; s++) {
    const unitree_hg_msg_dds__MotorCmd_ *m = &c->motor_cmd[s];
    if (!g[s].enabled) {
      if (m->mode != 0 || m->kp != 0.0f || m->kd != 0.0f) {
        if (!R.mismatch)
          snprintf(R.first_mismatch, sizeof R.first_mismatch, "slot %d is not driven by the spec but got mode %d kp %g kd %g",
                   s, m->mode, m->kp, m->kd);
        R.mismatch++;
        return;
      }
      continue;
    }
    if (m->mode != 1) all_st = all_po = all_damp = 0;
    if (!(m->kp == g[s].st_kp && m->kd == g[s].st_kd)) all_st = 0;
    if (!(m->kp == g[s].po_kp && m->kd == g[s].po_kd)) all_po = 0;
    if (!(m->kp == 0.0f && m->kd == g[s].damp_kd)) all_damp = 0;
    if (!all_st && !all_po && !all_damp) {
      if (!R.mismatch)
        snprintf(R.first_mismatch, sizeof R.first_mismatch,
                 "command %ld slot %d: mode %d kp %g kd %g is none of startup (%g, %g), policy (%g, %g), damping (0, %g)",
                 R.cmds, s, m->mode, m->kp, m->kd, g[s].st_kp, g[s].st_kd, g[s].po_kp, g[s].po_kd, g[s].damp_kd);
      R.mismatch++;
      return;
    }
  }
  if (all_damp)
    R.damping++;
  else if (all_po)
    R.policy++;
  else
    R.startup++;
}

static int active(const struct fault *f, const char *kind, double t) {
  return strcmp(f->kind, kind) == 0 && t >= f->start && t < f->start + f->dur;
}

int main(int argc, char **argv) {
  int robot_domain = -1, ctrl_domain = -1;
  const char *gains_path = NULL;
  double idle_exit = 2.0, max_time = 1e9;
  struct fault faults[MAX_FAULTS];
  int nf = 0;
  for (int i = 1; i < argc; i++) {
    if (i + 1 >= argc) die_usage("every option takes a value");
    if (!strcmp(argv[i], "--robot-domain"))
      robot_domain = atoi(argv[++i]);
    else if (!strcmp(argv[i], "--controller-domain"))
      ctrl_domain = atoi(argv[++i]);
    else if (!strcmp(argv[i], "--gains"))
      gains_path = argv[++i];
    else if (!strcmp(argv[i], "--idle-exit"))
      idle_exit = atof(argv[++i]);
    else if (!strcmp(argv[i], "--max-time"))
      max_time = atof(argv[++i]);
    else if (!strcmp(argv[i], "--fault")) {
      if (nf == MAX_FAULTS) die_usage("too many faults");
      struct fault *f = &faults[nf++];
      f->dur = 1e9;
      f->fired = 0;
      const char *spec = argv[++i];
      const char *at = strchr(spec, '@');
      if (!at || at - spec >= (long)sizeof f->kind) die_usage("fault: KIND@T[+D]");
      memcpy(f->kind, spec, at - spec);
      f->kind[at - spec] = 0;
      f->start = atof(at + 1);
      const char *plus = strchr(at, '+');
      if (plus) f->dur = atof(plus + 1);
    } else
      die_usage("unknown option");
  }
  if (robot_domain < 0 || ctrl_domain < 0 || !gains_path) die_usage("need --robot-domain, --controller-domain and --gains");
  if (sizeof(LowCmd) != 1004 || sizeof(LowState) != 2092) {
    fprintf(stderr, "g1_dds_peer: C layout is %zu/%zu bytes, Unitree's is 1004/2092\n", sizeof(LowCmd), sizeof(LowState));
    return 2;
  }
  struct gains g[NMOTORS];
  memset(g, 0, sizeof g);
  FILE *gf = fopen(gains_path, "r");
  if (!gf) die_usage("cannot open the gains file");
  int slot;
  float a, b, c, d, e;
  while (fscanf(gf, "%d %f %f %f %f %f", &slot, &a, &b, &c, &d, &e) == 6) {
    if (slot < 0 || slot >= NMOTORS) die_usage("slot out of range in the gains file");
    g[slot] = (struct gains){1, a, b, c, d, e};
  }
  fclose(gf);

  dds_qos_t *rq = dds_create_qos();
  dds_qset_reliability(rq, DDS_RELIABILITY_BEST_EFFORT, 0);
  dds_qset_history(rq, DDS_HISTORY_KEEP_LAST, 1);
  dds_qos_t *wq = dds_create_qos();
  dds_qset_reliability(wq, DDS_RELIABILITY_RELIABLE, DDS_MSECS(100));
  dds_qset_history(wq, DDS_HISTORY_KEEP_LAST, 1);

  dds_entity_t pr = check(dds_create_participant(robot_domain, NULL, NULL), "robot-side participant");
  dds_entity_t pc = check(dds_create_participant(ctrl_domain, NULL, NULL), "controller-side participant");
  dds_entity_t r_state_t = check(dds_create_topic(pr, &unitree_hg_msg_dds__LowState__desc, "rt/lowstate", NULL, NULL), "topic");
  dds_entity_t r_cmd_t = check(dds_create_topic(pr, &unitree_hg_msg_dds__LowCmd__desc, "rt/lowcmd", NULL, NULL), "topic");
  dds_entity_t c_state_t = check(dds_create_topic(pc, &unitree_hg_msg_dds__LowState__desc, "rt/lowstate", NULL, NULL), "topic");
  dds_entity_t c_cmd_t = check(dds_create_topic(pc, &unitree_hg_msg_dds__LowCmd__desc, "rt/lowcmd", NULL, NULL), "topic");
  dds_entity_t from_robot = check(dds_create_reader(pr, r_state_t, rq, NULL), "reader");
  dds_entity_t to_robot = check(dds_create_writer(pr, r_cmd_t, wq, NULL), "writer");
  dds_entity_t to_ctrl = check(dds_create_writer(pc, c_state_t, wq, NULL), "writer");
  dds_entity_t from_ctrl = check(dds_create_reader(pc, c_cmd_t, rq, NULL), "reader");
  dds_entity_t ws = check(dds_create_waitset(DDS_CYCLONEDDS_HANDLE), "waitset");
  dds_entity_t rc1 = check(dds_create_readcondition(from_robot, DDS_ANY_STATE), "readcondition");
  dds_entity_t rc2 = check(dds_create_readcondition(from_ctrl, DDS_ANY_STATE), "readcondition");
  check(dds_waitset_attach(ws, rc1, 1), "attach");
  check(dds_waitset_attach(ws, rc2, 2), "attach");
  dds_entity_t second_writer = 0, short_writer = 0;

  LowState st, frozen;
  LowCmd cmd;
  int have_state = 0, have_frozen = 0;
  uint8_t mode_machine = 0;
  double last_cmd_at = 0;
  fprintf(stderr, "g1_dds_peer: relaying robot domain %d <-> controller domain %d\n", robot_domain, ctrl_domain);
  R.end = "idle";
  for (;;) {
    dds_attach_t fired[2];
    dds_waitset_wait(ws, fired, 2, DDS_MSECS(20));
    double t = R.cmds * 0.002;
    void *ptr[1];
    dds_sample_info_t info;
    /* The robot's state: check, apply faults, republish with our own CRC. */
    for (;;) {
      memset(&st, 0, sizeof st);
      ptr[0] = &st;
      if (dds_take(from_robot, ptr, &info, 1, 1) <= 0) break;
      if (!info.valid_data) continue;
      R.states_in++;
      if (CRC_OF(st) != st.crc) R.state_crc_bad_from_robot++;
      mode_machine = st.mode_machine;
      have_state = 1;
      LowState out = st;
      int stale = 0, bad_crc = 0, short_too = 0;
      for (int i = 0; i < nf; i++) {
        if (active(&faults[i], "stale", t)) stale = faults[i].fired = 1;
        if (active(&faults[i], "crc", t)) bad_crc = faults[i].fired = 1;
        if (active(&faults[i], "size", t)) short_too = faults[i].fired = 1;
      }
      if (stale) {
        if (!have_frozen) {
          frozen = st;
          have_frozen = 1;
        }
        out = frozen;
      } else {
        have_frozen = 0;
      }
      /* The robot names another variant: 9 is the dual-arm G1, which has no legs. */
      for (int i = 0; i < nf; i++)
        if (active(&faults[i], "variant", t)) {
          out.mode_machine = 9;
          faults[i].fired = 1;
        }
      out.crc = CRC_OF(out);
      if (bad_crc) out.crc ^= 0x5a5a5a5au;
      if (dds_write(to_ctrl, &out) == DDS_RETCODE_OK) R.states_out++;
      if (short_too) {
        if (!short_writer) {
          dds_entity_t pb = check(dds_create_participant(ctrl_domain, NULL, NULL), "participant");
          dds_entity_t tb = check(dds_create_topic(pb, &short_state_LowState__desc, "rt/lowstate", NULL, NULL), "short topic");
          short_writer = check(dds_create_writer(pb, tb, wq, NULL), "short writer");
        }
        short_state_LowState_ s = {.version = {out.version[0], out.version[1]}, .mode_machine = out.mode_machine, .tick = out.tick};
        if (dds_write(short_writer, &s) == DDS_RETCODE_OK) R.short_out++;
      }
    }
    /* The controller's command: check CRC, echo and gains, forward. */
    for (;;) {
      memset(&cmd, 0, sizeof cmd);
      ptr[0] = &cmd;
      if (dds_take(from_ctrl, ptr, &info, 1, 1) <= 0) break;
      if (!info.valid_data) continue;
      R.cmds++;
      last_cmd_at = now_s();
      if (CRC_OF(cmd) == cmd.crc)
        R.cmd_crc_ok++;
      else
        R.cmd_crc_bad++;
      if (have_state && cmd.mode_machine != mode_machine) R.mode_machine_mismatch++;
      classify(&cmd, g);
      dds_write(to_robot, &cmd);
    }
    t = R.cmds * 0.002;
    R.t_end = t;
    for (int i = 0; i < nf; i++) {
      if (!strcmp(faults[i].kind, "writer") && t >= faults[i].start && !second_writer) {
        second_writer = check(dds_create_writer(pc, c_cmd_t, wq, NULL), "second rt/lowcmd writer");
        faults[i].fired = 1;
      }
      if (!strcmp(faults[i].kind, "die") && t >= faults[i].start) {
        faults[i].fired = 1;
        R.end = "died";
        report(faults, nf);
        _exit(0);
      }
    }
    if (t >= max_time) {
      R.end = "max_time";
      break;
    }
    if (last_cmd_at > 0 && now_s() - last_cmd_at > idle_exit) break;
  }
  report(faults, nf);
  dds_delete(pr);
  dds_delete(pc);
  return 0;
}
