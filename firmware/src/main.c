/* hdrd-adc: the CRS03-04 gyro's USB ADC on an ATmega328P (Arduino Uno / Nano class).
 *
 * Samples the gyro output on A0 and the supply monitor on A1 with the chip's 10-bit ADC
 * against AVCC, oversamples and decimates to one frame per 1/HDR_RATE_HZ s, and sends the
 * frames over the UART in hdr-bin (default) or hdr-text (docs/protocol.md). Wiring, scaling
 * and the matching hdrd configuration: docs/firmware.md.
 *
 * Timing. Timer1 (clk/8) divides each frame period into SLOTS_PER_FRAME equal slots. Its
 * compare interrupt, at the start of every slot, reads the conversion started one slot
 * earlier (13 ADC clocks = 104 us at 16 MHz: done well inside the 125 us slot at 100 Hz)
 * and starts the next one, so every conversion starts at a fixed instant after a timer edge
 * and the samples are evenly spread over the frame. Four slots in five sample A0, the fifth
 * A1: 64 rate and 16 supply conversions per frame.
 *
 * Scaling. rate = the sum of the frame's 64 ten-bit codes: sum/64 is the mean code, so
 * rate * Vref / 65536 is the mean input voltage, exactly hdrd's 16-bit model
 * (sensor.adc_bits: 16). ref = 4 x the sum of 16 codes, on the same scale. The largest
 * value is 1023 * 64 = 65472.
 *
 * Clock. t_us is a 32-bit microsecond count, advanced by SLOT_US in every slot interrupt
 * (exact: a slot is a whole number of microseconds), wrapping at 2**32 as the protocol
 * says. A frame's t_us is the start of its first conversion slot; the frame averages the
 * FRAME_US that follow.
 */
#include <avr/interrupt.h>
#include <avr/io.h>
#include <avr/sleep.h>
#include <avr/wdt.h>
#include <stdint.h>

#include "frame.h"

/* ---- build options (Makefile: RATE_HZ, PROTOCOL, BAUD, REF, T0_US, SEQ0) ---------------- */
#ifndef F_CPU
#error "F_CPU must be defined (the Makefile sets it)"
#endif
#ifndef HDR_RATE_HZ
#define HDR_RATE_HZ 100 /* frames per second */
#endif
#ifndef HDR_PROTOCOL_TEXT
#define HDR_PROTOCOL_TEXT 0 /* 0: hdr-bin, 1: hdr-text */
#endif
#ifndef HDR_BAUD
#define HDR_BAUD 115200
#endif
#ifndef HDR_REF_WIRED
#define HDR_REF_WIRED 1 /* 1: supply monitor on A1; 0: not wired, ref = 0 */
#endif
#ifndef HDR_T0_US
#define HDR_T0_US 0UL /* device clock at the first frame (tests start it near the wrap) */
#endif
#ifndef HDR_SEQ0
#define HDR_SEQ0 0U /* seq of the first frame */
#endif

/* ---- derived timing, checked at compile time -------------------------------------------- */
#define RATE_PER_FRAME 64u /* A0 conversions per frame: 4**3, +3 bits */
#define REF_PER_FRAME 16u  /* A1 conversions per frame */
#define SLOTS_PER_FRAME (RATE_PER_FRAME + REF_PER_FRAME)
#define REF_EVERY 5u /* every 5th slot samples A1 */
#define REF_SCALE 4u /* RATE_PER_FRAME / REF_PER_FRAME: ref on the rate's 16-bit scale */

#define FRAME_US (1000000UL / HDR_RATE_HZ)
#define SLOT_US (FRAME_US / SLOTS_PER_FRAME)
#define TIMER_TICKS_PER_US (F_CPU / 8UL / 1000000UL) /* Timer1 at clk/8 */
#define SLOT_TICKS (SLOT_US * TIMER_TICKS_PER_US)

#define ADC_CLOCK_HZ 125000UL /* inside the 50..200 kHz the datasheet gives for 10 bits */
#define ADC_PRESCALE (F_CPU / ADC_CLOCK_HZ)
#define CONVERSION_US (13UL * 1000000UL / ADC_CLOCK_HZ) /* 104 us */

_Static_assert(F_CPU % 8000000UL == 0, "F_CPU must be 8 or 16 MHz (whole timer ticks per us)");
_Static_assert(1000000UL % HDR_RATE_HZ == 0, "RATE_HZ must divide 1 000 000 (whole us per frame)");
_Static_assert(FRAME_US % SLOTS_PER_FRAME == 0, "the frame period must be a multiple of 80 us");
_Static_assert(SLOT_TICKS >= 1 && SLOT_TICKS <= 65536UL, "slot does not fit Timer1");
_Static_assert(SLOT_US >= CONVERSION_US + 16, "RATE_HZ too high: a conversion must end in its slot");
_Static_assert(RATE_PER_FRAME == REF_PER_FRAME * REF_SCALE, "ref scale");
_Static_assert(SLOTS_PER_FRAME == REF_PER_FRAME * REF_EVERY, "slot pattern");
_Static_assert(1023UL * RATE_PER_FRAME <= 65535UL, "the rate sum must fit 16 bits");
_Static_assert(ADC_PRESCALE == 64 || ADC_PRESCALE == 128, "ADC prescaler");
#if HDR_PROTOCOL_TEXT
_Static_assert(HDR_TEXT_MAX * 10UL * 1000000UL / HDR_BAUD < FRAME_US, "BAUD too low for hdr-text");
#else
_Static_assert(HDR_BIN_LEN * 10UL * 1000000UL / HDR_BAUD < FRAME_US, "BAUD too low for hdr-bin");
#endif

/* ---- UART: interrupt-driven transmit ring -------------------------------------------- */
#define BAUD HDR_BAUD
#define BAUD_TOL 3 /* 115200 at 16 MHz is +2.1 % (U2X, UBRR 16), as every Arduino sends it */
#include <util/setbaud.h>
#if USE_2X
#define BAUD_REAL (F_CPU / (8UL * (UBRR_VALUE + 1UL)))
#else
#define BAUD_REAL (F_CPU / (16UL * (UBRR_VALUE + 1UL)))
#endif
_Static_assert(100UL * BAUD_REAL <= 103UL * HDR_BAUD && 100UL * BAUD_REAL >= 97UL * HDR_BAUD,
               "BAUD: this clock cannot make that speed within 3 % (at 8 MHz use 57600)");

#define TX_SIZE 64u /* power of two, > HDR_TEXT_MAX */
static uint8_t tx_buf[TX_SIZE];
static volatile uint8_t tx_head; /* written by main */
static volatile uint8_t tx_tail; /* written by the UDRE interrupt */

ISR(USART_UDRE_vect)
{
    uint8_t t = tx_tail;
    if (t == tx_head) {
        UCSR0B &= (uint8_t)~_BV(UDRIE0); /* nothing left: stop asking */
        return;
    }
    UDR0 = tx_buf[t];
    tx_tail = (uint8_t)((t + 1u) & (TX_SIZE - 1u));
}

/* Sleep (idle: timers, ADC and UART run) until the next interrupt, without the race
 * between testing a condition and sleeping: call with interrupts disabled. */
static void sleep_until_interrupt(void)
{
    sleep_enable();
    sei(); /* the instruction after SEI runs before any pending interrupt: no lost wake-up */
    sleep_cpu();
    sleep_disable();
}

static void tx_write(const uint8_t *p, uint8_t n)
{
    while (n--) {
        uint8_t next = (uint8_t)((tx_head + 1u) & (TX_SIZE - 1u));
        cli();
        while (next == tx_tail) { /* full: wait for the transmitter */
            sleep_until_interrupt();
            cli();
        }
        sei();
        tx_buf[tx_head] = *p++;
        tx_head = next;
        UCSR0B |= _BV(UDRIE0);
    }
}

static void uart_init(void)
{
    UBRR0H = UBRRH_VALUE;
    UBRR0L = UBRRL_VALUE;
#if USE_2X
    UCSR0A = _BV(U2X0);
#else
    UCSR0A = 0;
#endif
    UCSR0C = _BV(UCSZ01) | _BV(UCSZ00); /* 8N1 */
    UCSR0B = _BV(TXEN0);
}

/* ---- sampling ------------------------------------------------------------------------ */
#define ADMUX_BASE _BV(REFS0) /* reference AVCC (the board's 5 V), capacitor at AREF */
#if ADC_PRESCALE == 128
#define ADCSRA_BASE (_BV(ADEN) | _BV(ADPS2) | _BV(ADPS1) | _BV(ADPS0))
#else
#define ADCSRA_BASE (_BV(ADEN) | _BV(ADPS2) | _BV(ADPS1))
#endif

enum { CH_NONE = 0, CH_RATE, CH_REF };

/* One finished frame, handed from the slot interrupt to the main loop. frame_ready is the
 * handshake; out is only touched by main with interrupts disabled (cli/sei are compiler
 * memory barriers), and by the interrupt only while frame_ready is 0. */
static hdr_sample_t out;
static volatile uint8_t frame_ready;
static volatile uint16_t frames_dropped; /* main was too slow (never seen at 100 Hz) */

ISR(TIMER1_COMPA_vect)
{
    static uint8_t slot;    /* slot now starting, 0 .. SLOTS_PER_FRAME-1 */
    static uint8_t phase;   /* slot % REF_EVERY */
    static uint8_t pending; /* channel of the conversion started one slot ago */
    static uint16_t rate_sum, ref_sum;
    static uint32_t clock_us = HDR_T0_US; /* device time at the start of this slot */
    static uint32_t frame_t_us;
    static uint16_t seq = HDR_SEQ0;
    static uint8_t started;

    if (pending == CH_RATE)
        rate_sum += ADC;
    else if (pending == CH_REF)
        ref_sum += ADC;

    if (slot == 0) {
        if (started) { /* every conversion of the frame begun SLOTS_PER_FRAME slots ago is in */
            if (!frame_ready) {
                out.seq = seq;
                out.t_us = frame_t_us;
                out.rate = rate_sum;
                out.ref = HDR_REF_WIRED ? (uint16_t)(ref_sum * REF_SCALE) : 0;
                out.temp = HDR_TEMP_ABSENT;
                frame_ready = 1;
            } else {
                frames_dropped++; /* its seq is skipped: the receiver counts it lost */
            }
            seq++;
        }
        started = 1;
        rate_sum = 0;
        ref_sum = 0;
        frame_t_us = clock_us;
    }

    pending = (phase == REF_EVERY - 1u) ? CH_REF : CH_RATE;
    if (pending == CH_REF && !HDR_REF_WIRED)
        pending = CH_NONE;
    if (pending != CH_NONE) {
        ADMUX = ADMUX_BASE | (pending == CH_REF ? 1u : 0u);
        ADCSRA = ADCSRA_BASE | _BV(ADSC);
    }

    if (++phase == REF_EVERY)
        phase = 0;
    if (++slot == SLOTS_PER_FRAME)
        slot = 0;
    clock_us += SLOT_US; /* uint32_t: wraps at 2**32 us */
}

static void adc_init(void)
{
    DIDR0 = _BV(ADC0D) | _BV(ADC1D); /* no digital input buffers on the analog pins */
    ADMUX = ADMUX_BASE;
    ADCSRA = ADCSRA_BASE | _BV(ADSC); /* the first conversion takes 25 ADC clocks: do it now */
    while (ADCSRA & _BV(ADSC)) {
    }
    (void)ADC;
}

static void timer_init(void)
{
    TCCR1A = 0;
    TCCR1B = _BV(WGM12) | _BV(CS11); /* CTC on OCR1A, clk/8 */
    OCR1A = (uint16_t)(SLOT_TICKS - 1u);
    TCNT1 = 0;
    TIMSK1 = _BV(OCIE1A);
}

int main(void)
{
    MCUSR = 0; /* a watchdog reset leaves the watchdog on: clear it before it fires again */
    wdt_disable();
    uart_init();
    adc_init();
    timer_init();
    SMCR = 0; /* sleep mode idle (SM2..0 = 000): timers, ADC and UART keep running */
    wdt_enable(WDTO_250MS); /* no frame sent for 250 ms: reset (hdrd sees a seq reset) */
    sei();

    for (;;) {
        cli();
        if (!frame_ready) {
            sleep_until_interrupt();
            continue;
        }
        hdr_sample_t s = out;
        frame_ready = 0;
        sei();
#if HDR_PROTOCOL_TEXT
        char line[HDR_TEXT_MAX];
        uint8_t n = hdr_encode_text(&s, line);
        tx_write((const uint8_t *)line, n);
#else
        uint8_t frame[HDR_BIN_LEN];
        uint8_t n = hdr_encode_bin(&s, frame);
        tx_write(frame, n);
#endif
        wdt_reset();
    }
}
