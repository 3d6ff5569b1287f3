/* hdrd-adc-sim: run the hdrd-adc firmware in simavr on an analog waveform.
 *
 *   hdrd-adc-sim --firmware ELF WAVE.csv OUT.bin [--seconds N] [options]
 *
 * WAVE.csv has rows "t, rate_volts, supply_volts" (s, V at the gyro's output, V of the
 * gyro's supply), one optional header line and '#' comments; t increasing. Between rows
 * the voltages are interpolated linearly; before the first row and after the last they hold.
 *
 * The board around the chip (docs/firmware.md): A0 sees rate_volts (through the RC filter,
 * whose settling is the waveform's business); A1 sees supply_volts / --ref-divider; the ADC
 * reference AVCC is --vcc (or, with --vcc supply, the waveform's supply: the gyro powered
 * from the board's own 5 V, which is then also the ADC's reference). simavr simulates the CPU, timers, ADC control and UART cycle by
 * cycle, but converts an input it is given in whole millivolts with code = mV * 1023 / Vref.
 * The harness therefore does the analog part itself, at the instant the chip samples
 * (1.5 ADC clocks after a conversion starts): input + Gaussian noise (--noise-lsb, the
 * converter's own transition noise and supply ripple, which dither the oversampling),
 * then the datasheet's ideal 10-bit transfer function, code = round(V * 1024 / Vref)
 * clipped to 0..1023 (first transition at 0.5 LSB), and hands simavr the millivolt value
 * that its formula turns into exactly that code.
 *
 * Output: every byte the UART sends goes to OUT.bin (a capture for `hdrd replay`) and, with
 * --pty LINK, to a pseudo-terminal whose slave LINK points to (`hdrd run --port LINK`); the
 * simulation waits for a reader to open it. --adc-log FILE writes one 12-byte record per
 * conversion (uint64 cycle, uint16 channel, uint16 code, little-endian) so a test can check
 * the firmware's sums against the codes it was given.
 *
 * At the end it prints one line on stderr: simulated seconds, wall seconds, bytes, conversions.
 */
#define _GNU_SOURCE
#include <errno.h>
#include <fcntl.h>
#include <math.h>
#include <poll.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/ioctl.h>
#include <termios.h>
#include <time.h>
#include <unistd.h>

#include <sim_avr.h>
#include <sim_elf.h>
#include <avr_adc.h>
#include <avr_uart.h>
#include <sim_irq.h>

/* ---- options ------------------------------------------------------------------------ */
static const char *opt_firmware, *opt_wave, *opt_out, *opt_pty, *opt_adc_log;
static double opt_seconds = -1;  /* < 0: until the waveform's last row */
static double opt_vcc = 5.0;     /* AVCC = ADC reference, V */
static int opt_vcc_is_supply;    /* --vcc supply: AVCC is the gyro's supply (one 5 V rail) */
static double opt_ref_divider = 2.0;
static double opt_noise_lsb = 0.5;
static double opt_speedup = 0;   /* 0: as fast as possible; 1: real time */
static uint64_t opt_seed = 1;
static const char *opt_mcu = "atmega328p";
static uint32_t opt_f_cpu = 16000000;

static void usage(FILE *f)
{
    fprintf(f,
            "usage: hdrd-adc-sim --firmware ELF WAVE.csv OUT.bin [--seconds N] [--pty LINK]\n"
            "         [--adc-log FILE] [--noise-lsb X] [--seed N] [--vcc V|supply] [--ref-divider R]\n"
            "         [--speedup X] [--mcu NAME] [--f-cpu HZ]\n");
}

static void die(const char *msg, const char *arg)
{
    fprintf(stderr, "hdrd-adc-sim: %s%s%s\n", msg, arg ? ": " : "", arg ? arg : "");
    exit(2);
}

static double number(const char *name, const char *s, double lo, double hi)
{
    char *end;
    errno = 0;
    double v = strtod(s, &end);
    if (errno || end == s || *end || !(v >= lo && v <= hi)) {
        fprintf(stderr, "hdrd-adc-sim: %s %s: expected a number in [%g, %g]\n", name, s, lo, hi);
        exit(2);
    }
    return v;
}

static void parse_args(int argc, char **argv)
{
    int positional = 0;
    for (int i = 1; i < argc; i++) {
        const char *a = argv[i];
        if (!strcmp(a, "-h") || !strcmp(a, "--help")) {
            usage(stdout);
            exit(0);
        }
        if (a[0] == '-' && a[1] == '-') {
            if (i + 1 >= argc)
                die("missing value after", a);
            const char *v = argv[++i];
            if (!strcmp(a, "--firmware")) opt_firmware = v;
            else if (!strcmp(a, "--seconds")) opt_seconds = number(a, v, 0, 1e6);
            else if (!strcmp(a, "--pty")) opt_pty = v;
            else if (!strcmp(a, "--adc-log")) opt_adc_log = v;
            else if (!strcmp(a, "--noise-lsb")) opt_noise_lsb = number(a, v, 0, 100);
            else if (!strcmp(a, "--seed")) opt_seed = (uint64_t)number(a, v, 0, 4e9);
            else if (!strcmp(a, "--vcc") && !strcmp(v, "supply")) opt_vcc_is_supply = 1;
            else if (!strcmp(a, "--vcc")) opt_vcc = number(a, v, 1.8, 5.5);
            else if (!strcmp(a, "--ref-divider")) opt_ref_divider = number(a, v, 1, 100);
            else if (!strcmp(a, "--speedup")) opt_speedup = number(a, v, 0, 1e6);
            else if (!strcmp(a, "--mcu")) opt_mcu = v;
            else if (!strcmp(a, "--f-cpu")) opt_f_cpu = (uint32_t)number(a, v, 1e6, 32e6);
            else {
                usage(stderr);
                die("unknown option", a);
            }
        } else if (positional == 0) {
            opt_wave = a;
            positional++;
        } else if (positional == 1) {
            opt_out = a;
            positional++;
        } else {
            usage(stderr);
            die("too many arguments", a);
        }
    }
    if (!opt_firmware || !opt_wave || !opt_out) {
        usage(stderr);
        exit(2);
    }
}

/* ---- the waveform ------------------------------------------------------------------- */
static double *wt, *wrate, *wsupply;
static size_t wn;

static void load_wave(const char *path)
{
    FILE *f = fopen(path, "r");
    if (!f) {
        fprintf(stderr, "hdrd-adc-sim: cannot read %s: %s\n", path, strerror(errno));
        exit(2);
    }
    size_t cap = 1024;
    wt = malloc(cap * sizeof *wt);
    wrate = malloc(cap * sizeof *wrate);
    wsupply = malloc(cap * sizeof *wsupply);
    char line[512];
    unsigned long lineno = 0;
    while (fgets(line, sizeof line, f)) {
        lineno++;
        char *p = line;
        while (*p == ' ' || *p == '\t')
            p++;
        if (*p == '#' || *p == '\n' || *p == '\r' || *p == 0)
            continue;
        double t, r, s;
        if (sscanf(p, "%lf , %lf , %lf", &t, &r, &s) != 3) {
            if (lineno == 1 && wn == 0)
                continue; /* the header */
            fprintf(stderr, "hdrd-adc-sim: %s:%lu: expected \"t, rate_volts, supply_volts\"\n",
                    path, lineno);
            exit(2);
        }
        if (!isfinite(t) || !isfinite(r) || !isfinite(s) || (wn && !(t > wt[wn - 1]))) {
            fprintf(stderr, "hdrd-adc-sim: %s:%lu: t must increase and values be finite\n",
                    path, lineno);
            exit(2);
        }
        if (wn == cap) {
            cap *= 2;
            wt = realloc(wt, cap * sizeof *wt);
            wrate = realloc(wrate, cap * sizeof *wrate);
            wsupply = realloc(wsupply, cap * sizeof *wsupply);
            if (!wt || !wrate || !wsupply)
                die("out of memory", NULL);
        }
        wt[wn] = t;
        wrate[wn] = r;
        wsupply[wn] = s;
        wn++;
    }
    fclose(f);
    if (!wn)
        die("no rows in the waveform", path);
}

/* Linear interpolation at t; the cursor makes the (increasing) lookups O(1) on average. */
static double wave_at(const double *col, double t)
{
    static size_t k;
    if (t <= wt[0])
        return col[0];
    if (t >= wt[wn - 1])
        return col[wn - 1];
    if (wt[k] > t)
        k = 0;
    while (wt[k + 1] <= t)
        k++;
    double a = (t - wt[k]) / (wt[k + 1] - wt[k]);
    return col[k] + a * (col[k + 1] - col[k]);
}

/* ---- noise: splitmix64 + Box-Muller, reproducible from --seed ------------------------ */
static uint64_t rng_state;

static uint64_t splitmix64(void)
{
    uint64_t z = (rng_state += 0x9E3779B97F4A7C15ULL);
    z = (z ^ (z >> 30)) * 0xBF58476D1CE4E5B9ULL;
    z = (z ^ (z >> 27)) * 0x94D049BB133111EBULL;
    return z ^ (z >> 31);
}

static double gaussian(void)
{
    double u1 = ((double)(splitmix64() >> 11) + 1.0) / 9007199254740993.0; /* (0, 1] */
    double u2 = (double)(splitmix64() >> 11) / 9007199254740992.0;
    return sqrt(-2.0 * log(u1)) * cos(6.283185307179586 * u2);
}

/* ---- the simulated board ------------------------------------------------------------ */
static avr_t *avr;
static avr_irq_t *adc_irq;
static FILE *out_file, *adc_log;
static int pty_master = -1;
static uint64_t bytes_out, conversions;

#define ADCSRA_ADDR 0x7A /* ATmega328P ADC control and status register A */

static int reader_present(void)
{
    struct pollfd p = {.fd = pty_master, .events = 0};
    return poll(&p, 1, 0) >= 0 && !(p.revents & POLLHUP);
}

static void pty_write(uint8_t b)
{
    for (;;) {
        if (!reader_present())
            return; /* nobody has the port open: the byte goes nowhere, as on a real wire */
        struct pollfd p = {.fd = pty_master, .events = POLLOUT};
        if (poll(&p, 1, 50) <= 0 || !(p.revents & POLLOUT))
            continue;
        ssize_t n = write(pty_master, &b, 1);
        if (n == 1)
            return;
        if (n < 0 && errno != EAGAIN && errno != EINTR && errno != EIO) {
            perror("hdrd-adc-sim: pty");
            exit(1);
        }
    }
}

static void uart_out_hook(struct avr_irq_t *irq, uint32_t value, void *param)
{
    (void)irq;
    (void)param;
    uint8_t b = (uint8_t)value;
    if (fputc(b, out_file) == EOF) {
        perror("hdrd-adc-sim: writing the output");
        exit(1);
    }
    if (pty_master >= 0)
        pty_write(b);
    bytes_out++;
}

/* A conversion starts: give the ADC the code the real chip would convert. */
static void adc_trigger_hook(struct avr_irq_t *irq, uint32_t value, void *param)
{
    (void)irq;
    (void)param;
    union {
        avr_adc_mux_t mux;
        uint32_t v;
    } e = {.v = value};
    if (e.mux.kind != ADC_MUX_SINGLE || e.mux.src > 7)
        return;
    unsigned chan = e.mux.src;
    uint32_t prescale = 1u << (avr->data[ADCSRA_ADDR] & 7u);
    if (prescale == 1)
        prescale = 2;
    double t = (double)(avr->cycle + 3 * prescale / 2) / avr->frequency; /* sample and hold */
    double volts = 0;
    if (chan == 0)
        volts = wave_at(wrate, t);
    else if (chan == 1)
        volts = wave_at(wsupply, t) / opt_ref_divider;
    double vref_v = avr->avcc / 1000.0;
    if (opt_vcc_is_supply) { /* one rail feeds the gyro and AVCC: the reference moves with it */
        vref_v = wave_at(wsupply, t);
        if (!(vref_v >= 1.8 && vref_v <= 5.5)) {
            fprintf(stderr, "hdrd-adc-sim: --vcc supply: %.3f V at t = %.6f s is outside "
                            "the ATmega328P's 1.8 .. 5.5 V\n", vref_v, t);
            exit(1);
        }
        /* simavr only needs a reference in whole mV to map our code back (below) */
        avr->vcc = avr->avcc = avr->aref = (uint32_t)lround(vref_v * 1000);
    }
    uint32_t vref_mv = avr->avcc;
    double lsb = vref_v / 1024.0;
    double x = volts / lsb + opt_noise_lsb * gaussian();
    long code = lround(x);
    if (code < 0)
        code = 0;
    if (code > 1023)
        code = 1023;
    /* simavr converts mV * 1023 / vref (truncated): the smallest mV giving exactly `code`. */
    uint32_t mv = (uint32_t)(((uint64_t)code * vref_mv + 1022) / 1023);
    if (mv * 1023u / vref_mv != (uint32_t)code) {
        fprintf(stderr, "hdrd-adc-sim: no millivolt value gives code %ld at Vref %u mV\n", code,
                vref_mv);
        exit(1);
    }
    avr_raise_irq(adc_irq + ADC_IRQ_ADC0 + chan, mv);
    conversions++;
    if (adc_log) {
        uint8_t rec[12];
        uint64_t c = avr->cycle;
        for (int i = 0; i < 8; i++)
            rec[i] = (uint8_t)(c >> (8 * i));
        rec[8] = (uint8_t)chan;
        rec[9] = 0;
        rec[10] = (uint8_t)code;
        rec[11] = (uint8_t)(code >> 8);
        if (fwrite(rec, sizeof rec, 1, adc_log) != 1) {
            perror("hdrd-adc-sim: writing the ADC log");
            exit(1);
        }
    }
}

/* simavr's default sleep callback waits in real time while the chip sleeps: do not. */
static void no_sleep(avr_t *a, avr_cycle_count_t how_long)
{
    (void)a;
    (void)how_long;
}

static void open_pty(const char *link)
{
    pty_master = posix_openpt(O_RDWR | O_NOCTTY);
    if (pty_master < 0 || grantpt(pty_master) || unlockpt(pty_master))
        die("cannot open a pty", strerror(errno));
    const char *slave_name = ptsname(pty_master);
    int slave = open(slave_name, O_RDWR | O_NOCTTY);
    if (slave < 0)
        die("cannot open the pty slave", strerror(errno));
    struct termios tio;
    if (tcgetattr(slave, &tio) == 0) { /* binary-clean for readers that leave it as it is */
        cfmakeraw(&tio);
        tcsetattr(slave, TCSANOW, &tio);
    }
    close(slave); /* not kept open: poll() on the master then says (POLLHUP) whether a reader has it */
    fcntl(pty_master, F_SETFL, fcntl(pty_master, F_GETFL) | O_NONBLOCK);
    char tmp[4096];
    snprintf(tmp, sizeof tmp, "%s.tmp%d", link, (int)getpid());
    unlink(tmp);
    if (symlink(slave_name, tmp) || rename(tmp, link))
        die("cannot make the link", link);
    printf("%s\n", slave_name);
    fflush(stdout);
    /* Wait for the reader, then let its open-time flush (pyserial) pass. */
    while (!reader_present())
        usleep(20000);
    usleep(500000);
}

static double wall_s(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (double)ts.tv_sec + ts.tv_nsec / 1e9;
}

/* Before closing the pty, wait (at most 5 s) until the reader has taken every byte: the
 * queue must stay empty for 50 ms, as the kernel moves written bytes to it asynchronously. */
static void pty_drain(void)
{
    int fd = open(ptsname(pty_master), O_RDONLY | O_NOCTTY | O_NONBLOCK);
    if (fd < 0)
        return;
    double end = wall_s() + 5.0, empty_since = -1;
    while (reader_present() && wall_s() < end) {
        int queued = 0;
        if (ioctl(fd, FIONREAD, &queued))
            break;
        double now = wall_s();
        if (queued)
            empty_since = -1;
        else if (empty_since < 0)
            empty_since = now;
        else if (now - empty_since >= 0.05)
            break;
        usleep(5000);
    }
    close(fd);
}

int main(int argc, char **argv)
{
    parse_args(argc, argv);
    load_wave(opt_wave);
    rng_state = opt_seed;
    double seconds = opt_seconds >= 0 ? opt_seconds : wt[wn - 1];

    elf_firmware_t fw;
    memset(&fw, 0, sizeof fw);
    /* simavr prints "Loaded ..." on stdout: keep stdout for the pty's name */
    fflush(stdout);
    int saved_stdout = dup(1), devnull = open("/dev/null", O_WRONLY);
    if (saved_stdout >= 0 && devnull >= 0)
        dup2(devnull, 1);
    if (elf_read_firmware(opt_firmware, &fw))
        die("cannot read the firmware", opt_firmware);
    fflush(stdout);
    if (saved_stdout >= 0 && devnull >= 0) {
        dup2(saved_stdout, 1);
        close(saved_stdout);
        close(devnull);
    }
    avr = avr_make_mcu_by_name(opt_mcu);
    if (!avr)
        die("simavr does not know this MCU", opt_mcu);
    avr_init(avr);
    avr->log = LOG_WARNING;
    fw.frequency = opt_f_cpu;
    fw.vcc = fw.avcc = fw.aref = (uint32_t)lround(opt_vcc * 1000);
    avr_load_firmware(avr, &fw);
    avr->sleep = no_sleep;

    out_file = fopen(opt_out, "wb");
    if (!out_file)
        die("cannot write", opt_out);
    if (opt_adc_log && !(adc_log = fopen(opt_adc_log, "wb")))
        die("cannot write", opt_adc_log);

    uint32_t flags = 0; /* no copy of the UART's lines on our stdout */
    avr_ioctl(avr, AVR_IOCTL_UART_GET_FLAGS('0'), &flags);
    flags &= ~(uint32_t)AVR_UART_FLAG_STDIO;
    avr_ioctl(avr, AVR_IOCTL_UART_SET_FLAGS('0'), &flags);
    avr_irq_register_notify(avr_io_getirq(avr, AVR_IOCTL_UART_GETIRQ('0'), UART_IRQ_OUTPUT),
                            uart_out_hook, NULL);
    adc_irq = avr_io_getirq(avr, AVR_IOCTL_ADC_GETIRQ, 0);
    avr_irq_register_notify(adc_irq + ADC_IRQ_OUT_TRIGGER, adc_trigger_hook, NULL);

    if (opt_pty)
        open_pty(opt_pty);

    avr_cycle_count_t end = (avr_cycle_count_t)llround(seconds * avr->frequency);
    avr_cycle_count_t next_pace = 0, pace_step = avr->frequency / 100;
    double t0 = wall_s();
    int state = cpu_Running;
    while (avr->cycle < end) {
        state = avr_run(avr);
        if (state == cpu_Done || state == cpu_Crashed)
            break;
        if (opt_speedup > 0 && avr->cycle >= next_pace) { /* keep sim time / speedup <= wall */
            next_pace = avr->cycle + pace_step;
            double ahead = (double)avr->cycle / avr->frequency / opt_speedup - (wall_s() - t0);
            if (ahead > 0)
                usleep((useconds_t)(ahead * 1e6));
        }
    }
    double wall = wall_s() - t0;
    if (fclose(out_file) || (adc_log && fclose(adc_log)))
        die("cannot finish writing the output", NULL);
    if (opt_pty) {
        pty_drain();
        unlink(opt_pty);
        close(pty_master);
    }
    fprintf(stderr,
            "hdrd-adc-sim: %.3f s simulated in %.2f s wall (%.1fx real time), %llu bytes, "
            "%llu conversions\n",
            (double)avr->cycle / avr->frequency, wall,
            wall > 0 ? (double)avr->cycle / avr->frequency / wall : 0.0,
            (unsigned long long)bytes_out, (unsigned long long)conversions);
    if (state == cpu_Crashed) {
        fprintf(stderr, "hdrd-adc-sim: the firmware crashed\n");
        return 1;
    }
    return 0;
}
