/*
 * Enbarr Arduino PWM link: protocol and watchdog logic of the board, portable C99.
 *
 * The same source is compiled for the Arduino Mega 2560 (avr-gcc, the sketch
 * enbarr_arduino.ino wires it to Serial and the hardware timers) and with the host compiler
 * into a shared library that Enbarr's emulator (enbarr_plugins/arduino/emulator.py) loads
 * with ctypes, so the host driver is tested against this very code. No globals: every
 * state lives in one enb_link, so the host can run several boards in one process.
 *
 * API: enb_init() at power-on (outputs neutral, a HELLO queued), enb_rx() with the bytes
 * received, enb_tick(now_ms) often (the watchdog), enb_tx() to take the bytes to send,
 * enb_duty() for the output of each channel. Times are a free-running millisecond counter
 * (millis() on the board); wrap-around after 49 days is handled (unsigned differences).
 *
 * Frame on the wire (both directions), the frame of enbarr_plugins/transport/serial_link.py:
 *
 *     0xA5 | LEN | PAYLOAD (LEN bytes) | CRC hi | CRC lo
 *
 * CRC-16/CCITT-FALSE (poly 0x1021, init 0xFFFF, not reflected, xorout 0; check 0x29B1 for
 * "123456789"; Greg Cook's CRC catalogue, "CRC-16/IBM-3740") over LEN and PAYLOAD.
 * PAYLOAD = TYPE (1 byte) | SEQ (1 byte) | BODY. Multi-byte fields are big-endian.
 * Duties are in units of 0.01 % (685 = 6.85 %); at 50 Hz, 1 unit = 0.2 us of pulse.
 *
 * Host -> board (SEQ: the host's counter, +1 per frame, mod 256):
 *   0x01 HELLO_REQ  (no body)  start of a session: outputs neutral, the sequence restarts
 *                              at this frame's SEQ; the board answers HELLO.
 *   0x02 SET_DUTY   6 x u16    duty of channels 0..5; each within [duty_min, duty_max] or
 *                              the whole frame is refused (RESULT_RANGE).
 *   0x03 HEARTBEAT  (no body)  the host is alive: the outputs keep their duty.
 *   0x04 CONFIG     u16 duty_min, u16 duty_max, u16 timeout_ms, 6 x u16 neutral duty
 *                              (kept in RAM until reset; defaults below). Refused
 *                              (RESULT_RANGE) unless 1 <= duty_min < duty_max <= 10000,
 *                              timeout_ms >= 20 and every neutral within [duty_min,
 *                              duty_max]: a duty of 0 has no pulse the timers can make.
 * Board -> host (SEQ: the board's counter, 0 at reset, +1 per frame):
 *   0x81 HELLO      u8 protocol version, u16 board id, u8 channels, u16 timeout_ms,
 *                   u16 boot count, u8 reset cause. Sent at reset and for HELLO_REQ.
 *   0x82 STATUS     u8 acked SEQ, u8 result, u8 flags, u16 watchdog trips, u16 CRC errors,
 *                   u16 sequence errors, u16 refused frames, u16 truncated frames.
 *                   One per host frame (HELLO_REQ excepted), refused ones too.
 *
 * SEQ rule: a host frame is accepted when its SEQ is 1..127 ahead of the last accepted one
 * (mod 256); duplicates and older frames are refused (RESULT_SEQ) and counted, and they do
 * not feed the watchdog. Only accepted frames feed it: when none comes for timeout_ms the
 * board puts every channel to its neutral duty on its own and counts a watchdog trip; the
 * duties return only with the next SET_DUTY. A frame cut off by a silent line (no byte for
 * ENB_RX_GAP_MS) is dropped and counted as truncated.
 */
#ifndef ENBARR_LINK_H
#define ENBARR_LINK_H

#include <stddef.h>
#include <stdint.h>

#ifdef __cplusplus
extern "C" {
#endif

#define ENB_PROTOCOL_VERSION 1
#define ENB_BOARD_ID 0x4D45u          /* "ME": Enbarr's Mega PWM board */
#define ENB_CHANNELS 6
#define ENB_START 0xA5u
#define ENB_MAX_PAYLOAD 24            /* longer frames are refused while parsing */
#define ENB_TX_CAP 96                 /* bytes queued for sending */
#define ENB_RX_GAP_MS 20u             /* a partial frame silent this long is dropped */

#define ENB_DEFAULT_TIMEOUT_MS 250u
#define ENB_DEFAULT_DUTY_MIN 430u     /* 4.30 %: CS Saucer manual, Table 1.1 */
#define ENB_DEFAULT_DUTY_MAX 940u     /* 9.40 % */
#define ENB_DEFAULT_NEUTRAL 685u      /* 6.85 %: the Saucer's motor dead band middle, servo 0 */

/* Message types. */
#define ENB_HELLO_REQ 0x01u
#define ENB_SET_DUTY 0x02u
#define ENB_HEARTBEAT 0x03u
#define ENB_CONFIG 0x04u
#define ENB_HELLO 0x81u
#define ENB_STATUS 0x82u

/* STATUS result codes. */
#define ENB_RESULT_OK 0u
#define ENB_RESULT_SEQ 1u             /* duplicate or out-of-order SEQ */
#define ENB_RESULT_LENGTH 2u          /* wrong body length for the type */
#define ENB_RESULT_RANGE 3u           /* a duty (or CONFIG value) out of range */
#define ENB_RESULT_TYPE 4u            /* unknown type */

/* STATUS flags. */
#define ENB_FLAG_NEUTRAL 0x01u        /* every channel at its neutral duty */
#define ENB_FLAG_CONFIGURED 0x02u     /* a CONFIG was accepted since reset */
#define ENB_FLAG_TRIPPED 0x04u        /* neutral because the watchdog tripped */

/* Counters (enb_counter). */
enum enb_counter_id {
    ENB_C_FRAMES = 0,      /* good frames received (CRC right) */
    ENB_C_CRC_ERRORS,      /* CRC mismatches */
    ENB_C_SEQ_ERRORS,      /* duplicate / out-of-order frames refused */
    ENB_C_REFUSED,         /* frames refused for type, length or range */
    ENB_C_TRUNCATED,       /* partial frames dropped (silent line, too long) */
    ENB_C_WATCHDOG_TRIPS,  /* outputs put neutral by the watchdog */
    ENB_C_TX_DROPPED,      /* replies dropped because the send queue was full */
    ENB_C_BYTES_IN,        /* bytes received */
    ENB_C_COUNT
};

typedef struct enb_link {
    /* receiver */
    uint8_t rx_buf[ENB_MAX_PAYLOAD + 4];
    uint8_t rx_pos;
    uint32_t rx_last_ms;
    /* transmitter: a byte FIFO */
    uint8_t tx_buf[ENB_TX_CAP];
    uint16_t tx_head;
    uint16_t tx_count;
    uint8_t tx_seq;
    /* session */
    uint8_t have_seq;
    uint8_t last_seq;
    uint32_t last_valid_ms;
    uint8_t flags;
    /* outputs and configuration */
    uint16_t duty[ENB_CHANNELS];
    uint16_t neutral[ENB_CHANNELS];
    uint16_t duty_min;
    uint16_t duty_max;
    uint16_t timeout_ms;
    uint16_t boot_count;
    uint8_t reset_cause;
    uint16_t counters[ENB_C_COUNT];
} enb_link;

/* CRC-16/CCITT-FALSE of data, continued from crc (start with 0xFFFF). */
uint16_t enb_crc16(const uint8_t *data, uint16_t n, uint16_t crc);

/* Power-on: default configuration, outputs neutral, a HELLO queued. */
void enb_init(enb_link *link, uint32_t now_ms, uint16_t boot_count, uint8_t reset_cause);

/* Feed received bytes. */
void enb_rx(enb_link *link, const uint8_t *data, uint16_t n, uint32_t now_ms);

/* Run the watchdog and the partial-frame timeout; call at least every few ms. */
void enb_tick(enb_link *link, uint32_t now_ms);

/* Move up to cap queued bytes into out; return how many. */
uint16_t enb_tx(enb_link *link, uint8_t *out, uint16_t cap);

/* Output duty of channel ch [0.01 %] (0 for a channel that does not exist). */
uint16_t enb_duty(const enb_link *link, uint8_t ch);

/* STATUS flags now (ENB_FLAG_*). */
uint8_t enb_flags(const enb_link *link);

/* Counter id (enum enb_counter_id); 0 for an unknown id. */
uint16_t enb_counter(const enb_link *link, uint8_t id);

/* sizeof(enb_link), for hosts that allocate the state themselves (ctypes). */
size_t enb_link_size(void);

#ifdef __cplusplus
}
#endif

#endif /* ENBARR_LINK_H */
