// Host build of the Curio base firmware: the portable core (curio_base/src) serving the real
// protocol on a pseudo-terminal, with a simulated LX-16A servo bus.
//
//   curio_fw_host [--boot-ms N] [--link PATH] [--quiet]
//
// Prints the pty path (or --link, a symlink to it) on stdout, then serves until SIGTERM/SIGINT.
// Like the Mega's DTR auto-reset, every time a client opens the port the board resets: it drops
// input for --boot-ms (the bootloader; the servos keep their last duty, as on the real rover),
// then runs setup() (wheels stopped, BOOT, INFO, DISARMED). SIGUSR1 resets it too (the reset
// button). State and wheel-duty changes are logged on stderr.
#include <errno.h>
#include <fcntl.h>
#include <poll.h>
#include <signal.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <termios.h>
#include <time.h>
#include <unistd.h>

#include <string>

#include "../curio_base/src/controller.h"
#include "sim_servos.h"

using namespace curio;

static volatile sig_atomic_t g_stop = 0;
static volatile sig_atomic_t g_reset = 0;
static void on_stop(int) { g_stop = 1; }
static void on_reset(int) { g_reset = 1; }

static uint64_t mono_ms() {
  struct timespec ts;
  clock_gettime(CLOCK_MONOTONIC, &ts);
  return (uint64_t)ts.tv_sec * 1000u + (uint64_t)ts.tv_nsec / 1000000u;
}

class PtyHost : public HostLink {
 public:
  int fd = -1;
  bool open = false;
  bool booting = true;
  uint32_t dropped = 0;
  void write(const uint8_t* data, size_t n) override {
    if (!open || booting) return;
    ssize_t w = ::write(fd, data, n);
    if (w < 0 && errno != EAGAIN) open = false;
    if (w < (ssize_t)n) dropped += (uint32_t)(n - (w < 0 ? 0 : w));
  }
};

static const char* state_name(uint8_t s) {
  static const char* names[] = {"BOOT", "DISARMED", "ARMED", "TIMEOUT", "ESTOP"};
  return s < 5 ? names[s] : "?";
}

int main(int argc, char** argv) {
  uint32_t boot_ms = 500;
  std::string link;
  bool quiet = false;
  for (int i = 1; i < argc; ++i) {
    std::string a = argv[i];
    if (a == "--boot-ms" && i + 1 < argc) boot_ms = (uint32_t)atoi(argv[++i]);
    else if (a == "--link" && i + 1 < argc) link = argv[++i];
    else if (a == "--quiet") quiet = true;
    else {
      fprintf(stderr, "usage: %s [--boot-ms N] [--link PATH] [--quiet]\n", argv[0]);
      return 2;
    }
  }
  int master = posix_openpt(O_RDWR | O_NOCTTY);
  if (master < 0 || grantpt(master) != 0 || unlockpt(master) != 0) {
    perror("posix_openpt");
    return 1;
  }
  const char* slave_name = ptsname(master);
  int slave = ::open(slave_name, O_RDWR | O_NOCTTY);
  struct termios tio;
  tcgetattr(slave, &tio);
  cfmakeraw(&tio);
  tcsetattr(slave, TCSANOW, &tio);
  ::close(slave);  // from now on the master reports POLLHUP until a client opens the port
  fcntl(master, F_SETFL, fcntl(master, F_GETFL) | O_NONBLOCK);
  if (!link.empty()) {
    unlink(link.c_str());
    if (symlink(slave_name, link.c_str()) != 0) {
      perror("symlink");
      return 1;
    }
  }
  printf("%s\n", link.empty() ? slave_name : link.c_str());
  fflush(stdout);
  signal(SIGTERM, on_stop);
  signal(SIGINT, on_stop);
  signal(SIGUSR1, on_reset);

  static const uint8_t ids[NUM_SERVOS] = {11, 12, 13, 21, 22, 23, 111, 131, 211, 231};
  SimServoBus bus(ids, NUM_SERVOS);
  PtyHost host;
  host.fd = master;
  Controller ctrl(host, bus);
  const uint64_t t0 = mono_ms();
  uint64_t boot_at = t0;  // power-on: boot at once
  uint8_t cause = 0x01;   // power-on reset
  uint8_t last_state = 0xFF;
  int16_t last_duty[NUM_WHEELS] = {0, 0, 0, 0, 0, 0};

  while (!g_stop) {
    uint32_t now = (uint32_t)(mono_ms() - t0);
    struct pollfd pfd = {master, POLLIN, 0};
    int timeout = host.open ? 1 : 0;
    poll(&pfd, 1, timeout);
    now = (uint32_t)(mono_ms() - t0);
    bool hup = (pfd.revents & POLLHUP) != 0;
    if (host.open && hup) {
      host.open = false;
      if (!quiet) fprintf(stderr, "t=%u host closed the port\n", now);
    } else if (!host.open && !hup) {
      host.open = true;
      g_reset = 1;  // DTR auto-reset on open
      if (!quiet) fprintf(stderr, "t=%u host opened the port: reset\n", now);
    }
    if (g_reset) {
      g_reset = 0;
      host.booting = true;
      boot_at = mono_ms() + boot_ms;
      cause = 0x02;  // external reset
    }
    if (host.open && (pfd.revents & POLLIN)) {
      uint8_t buf[256];
      ssize_t n = read(master, buf, sizeof buf);
      if (n > 0 && !host.booting) {
        for (ssize_t i = 0; i < n; ++i) ctrl.on_host_byte(buf[i], now);
      }
    }
    bus.advance(now);
    if (host.booting && mono_ms() >= boot_at) {
      host.booting = false;
      ctrl.boot(now, cause);
    }
    if (!host.booting) {
      uint64_t before = mono_ms();
      ctrl.poll(now);
      ctrl.note_loop_us((uint16_t)((mono_ms() - before) * 1000u));
    }
    if (!quiet) {
      const SimServo* s[NUM_WHEELS];
      bool changed = ctrl.state() != last_state;
      for (uint8_t i = 0; i < NUM_WHEELS; ++i) {
        s[i] = bus.servo(ids[i]);
        if (s[i]->duty != last_duty[i]) changed = true;
      }
      if (changed) {
        last_state = ctrl.state();
        fprintf(stderr, "t=%u state=%s duties=", now, state_name(last_state));
        for (uint8_t i = 0; i < NUM_WHEELS; ++i) {
          last_duty[i] = s[i]->duty;
          fprintf(stderr, "%s%d", i ? "," : "", last_duty[i]);
        }
        fprintf(stderr, "\n");
      }
    }
    if (!host.open) usleep(5000);  // nobody there: check for an open every 5 ms
  }
  if (!link.empty()) unlink(link.c_str());
  close(master);
  return 0;
}
