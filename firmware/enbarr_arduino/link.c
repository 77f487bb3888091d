/*
 * Enbarr Arduino PWM link: protocol and watchdog logic. The protocol is documented in
 * link.h and docs/hw/arduino.md.
 */
#include "link.h"

#include <string.h>

uint16_t enb_crc16(const uint8_t *data, uint16_t n, uint16_t crc)
{
    uint16_t i;
    uint8_t bit;
    for (i = 0; i < n; ++i) {
        crc ^= (uint16_t)data[i] << 8;
        for (bit = 0; bit < 8; ++bit) {
            crc = (crc & 0x8000u) ? (uint16_t)((crc << 1) ^ 0x1021u) : (uint16_t)(crc << 1);
        }
    }
    return crc;
}

static void count(enb_link *link, uint8_t id)
{
    if (link->counters[id] != 0xFFFFu) {
        ++link->counters[id];
    }
}

static uint16_t get_u16(const uint8_t *p)
{
    return (uint16_t)(((uint16_t)p[0] << 8) | p[1]);
}

static uint8_t *put_u16(uint8_t *p, uint16_t v)
{
    p[0] = (uint8_t)(v >> 8);
    p[1] = (uint8_t)(v & 0xFFu);
    return p + 2;
}

static void queue_frame(enb_link *link, const uint8_t *payload, uint8_t len)
{
    uint8_t head[2];
    uint8_t tail[2];
    uint16_t crc;
    uint16_t i;
    uint16_t n = (uint16_t)len + 4u;
    if (link->tx_count + n > ENB_TX_CAP) {
        count(link, ENB_C_TX_DROPPED);
        return;
    }
    head[0] = ENB_START;
    head[1] = len;
    crc = enb_crc16(&head[1], 1, 0xFFFFu);
    crc = enb_crc16(payload, len, crc);
    put_u16(tail, crc);
    for (i = 0; i < n; ++i) {
        uint8_t b = i < 2 ? head[i] : (i < 2u + len ? payload[i - 2] : tail[i - 2 - len]);
        link->tx_buf[(link->tx_head + link->tx_count) % ENB_TX_CAP] = b;
        ++link->tx_count;
    }
    ++link->tx_seq;
}

static void go_neutral(enb_link *link)
{
    memcpy(link->duty, link->neutral, sizeof link->duty);
    link->flags |= ENB_FLAG_NEUTRAL;
}

static void update_neutral_flag(enb_link *link)
{
    if (memcmp(link->duty, link->neutral, sizeof link->duty) == 0) {
        link->flags |= ENB_FLAG_NEUTRAL;
    } else {
        link->flags &= (uint8_t)~ENB_FLAG_NEUTRAL;
    }
}

static void send_hello(enb_link *link)
{
    uint8_t p[11];
    uint8_t *q = p;
    *q++ = ENB_HELLO;
    *q++ = link->tx_seq;
    *q++ = ENB_PROTOCOL_VERSION;
    q = put_u16(q, ENB_BOARD_ID);
    *q++ = ENB_CHANNELS;
    q = put_u16(q, link->timeout_ms);
    q = put_u16(q, link->boot_count);
    *q++ = link->reset_cause;
    queue_frame(link, p, (uint8_t)(q - p));
}

static void send_status(enb_link *link, uint8_t acked, uint8_t result)
{
    uint8_t p[15];
    uint8_t *q = p;
    *q++ = ENB_STATUS;
    *q++ = link->tx_seq;
    *q++ = acked;
    *q++ = result;
    *q++ = link->flags;
    q = put_u16(q, link->counters[ENB_C_WATCHDOG_TRIPS]);
    q = put_u16(q, link->counters[ENB_C_CRC_ERRORS]);
    q = put_u16(q, link->counters[ENB_C_SEQ_ERRORS]);
    q = put_u16(q, link->counters[ENB_C_REFUSED]);
    q = put_u16(q, link->counters[ENB_C_TRUNCATED]);
    queue_frame(link, p, (uint8_t)(q - p));
}

void enb_init(enb_link *link, uint32_t now_ms, uint16_t boot_count, uint8_t reset_cause)
{
    uint8_t ch;
    memset(link, 0, sizeof *link);
    link->duty_min = ENB_DEFAULT_DUTY_MIN;
    link->duty_max = ENB_DEFAULT_DUTY_MAX;
    link->timeout_ms = ENB_DEFAULT_TIMEOUT_MS;
    for (ch = 0; ch < ENB_CHANNELS; ++ch) {
        link->neutral[ch] = ENB_DEFAULT_NEUTRAL;
    }
    link->boot_count = boot_count;
    link->reset_cause = reset_cause;
    link->last_valid_ms = now_ms;
    link->rx_last_ms = now_ms;
    go_neutral(link);
    send_hello(link);
}

/* Body length each host type must have; -1 for an unknown type. */
static int body_length(uint8_t type)
{
    switch (type) {
    case ENB_HELLO_REQ:
    case ENB_HEARTBEAT:
        return 0;
    case ENB_SET_DUTY:
        return 2 * ENB_CHANNELS;
    case ENB_CONFIG:
        return 6 + 2 * ENB_CHANNELS;
    default:
        return -1;
    }
}

static void handle(enb_link *link, const uint8_t *p, uint8_t len, uint32_t now_ms)
{
    uint8_t type;
    uint8_t seq;
    uint8_t ch;
    uint8_t ahead;
    const uint8_t *body = p + 2;
    int want;
    if (len < 2) {
        count(link, ENB_C_REFUSED);
        send_status(link, 0, ENB_RESULT_LENGTH);
        return;
    }
    type = p[0];
    seq = p[1];
    want = body_length(type);
    if (want < 0) {
        count(link, ENB_C_REFUSED);
        send_status(link, seq, ENB_RESULT_TYPE);
        return;
    }
    if (len - 2 != want) {
        count(link, ENB_C_REFUSED);
        send_status(link, seq, ENB_RESULT_LENGTH);
        return;
    }
    if (type == ENB_HELLO_REQ) {  /* a new session: neutral, the sequence restarts here */
        link->have_seq = 1;
        link->last_seq = seq;
        link->last_valid_ms = now_ms;
        link->flags &= (uint8_t)~ENB_FLAG_TRIPPED;
        go_neutral(link);
        send_hello(link);
        return;
    }
    ahead = (uint8_t)(seq - link->last_seq);
    if (link->have_seq && (ahead == 0 || ahead > 127)) {
        count(link, ENB_C_SEQ_ERRORS);
        send_status(link, seq, ENB_RESULT_SEQ);
        return;
    }
    if (type == ENB_SET_DUTY) {
        for (ch = 0; ch < ENB_CHANNELS; ++ch) {
            uint16_t d = get_u16(body + 2 * ch);
            if (d < link->duty_min || d > link->duty_max) {
                count(link, ENB_C_REFUSED);
                send_status(link, seq, ENB_RESULT_RANGE);
                return;
            }
        }
        for (ch = 0; ch < ENB_CHANNELS; ++ch) {
            link->duty[ch] = get_u16(body + 2 * ch);
        }
        link->flags &= (uint8_t)~ENB_FLAG_TRIPPED;
        update_neutral_flag(link);
    } else if (type == ENB_CONFIG) {
        uint16_t lo = get_u16(body);
        uint16_t hi = get_u16(body + 2);
        uint16_t timeout = get_u16(body + 4);
        /* A duty of 0 cannot be output: the sketch's OCR = 4 * duty - 1 wraps to 0xFFFF,
         * above TOP, where no compare match clears the pin (a constant-high line). Every
         * duty is at least duty_min, so refusing a zero minimum refuses them all. */
        if (lo == 0u || lo >= hi || hi > 10000u || timeout < 20u) {
            count(link, ENB_C_REFUSED);
            send_status(link, seq, ENB_RESULT_RANGE);
            return;
        }
        for (ch = 0; ch < ENB_CHANNELS; ++ch) {
            uint16_t n = get_u16(body + 6 + 2 * ch);
            if (n < lo || n > hi) {
                count(link, ENB_C_REFUSED);
                send_status(link, seq, ENB_RESULT_RANGE);
                return;
            }
        }
        link->duty_min = lo;
        link->duty_max = hi;
        link->timeout_ms = timeout;
        for (ch = 0; ch < ENB_CHANNELS; ++ch) {
            link->neutral[ch] = get_u16(body + 6 + 2 * ch);
        }
        link->flags |= ENB_FLAG_CONFIGURED;
        go_neutral(link);  /* a new configuration starts neutral */
    }
    /* HEARTBEAT: nothing to change */
    link->have_seq = 1;
    link->last_seq = seq;
    link->last_valid_ms = now_ms;
    send_status(link, seq, ENB_RESULT_OK);
}

static void rx_byte(enb_link *link, uint8_t b, uint32_t now_ms);

/* The frame in rx_buf is bad: drop its start byte and search the rest again. */
static void resync(enb_link *link, uint32_t now_ms)
{
    uint8_t rest[ENB_MAX_PAYLOAD + 4];
    uint8_t n = (uint8_t)(link->rx_pos - 1);
    uint8_t i;
    memcpy(rest, link->rx_buf + 1, n);
    link->rx_pos = 0;
    for (i = 0; i < n; ++i) {
        rx_byte(link, rest[i], now_ms);
    }
}

static void rx_byte(enb_link *link, uint8_t b, uint32_t now_ms)
{
    uint8_t len;
    uint16_t crc;
    if (link->rx_pos == 0) {
        if (b == ENB_START) {
            link->rx_buf[link->rx_pos++] = b;
        }
        return;  /* bytes between frames are skipped */
    }
    link->rx_buf[link->rx_pos++] = b;
    len = link->rx_buf[1];
    if (link->rx_pos == 2 && len > ENB_MAX_PAYLOAD) {
        count(link, ENB_C_TRUNCATED);
        resync(link, now_ms);
        return;
    }
    if (link->rx_pos < 2 || link->rx_pos < (uint8_t)(len + 4u)) {
        return;
    }
    crc = enb_crc16(link->rx_buf + 1, (uint16_t)(len + 1u), 0xFFFFu);
    if (crc != get_u16(link->rx_buf + 2 + len)) {
        count(link, ENB_C_CRC_ERRORS);
        resync(link, now_ms);
        return;
    }
    count(link, ENB_C_FRAMES);
    link->rx_pos = 0;
    handle(link, link->rx_buf + 2, len, now_ms);
}

void enb_rx(enb_link *link, const uint8_t *data, uint16_t n, uint32_t now_ms)
{
    uint16_t i;
    enb_tick(link, now_ms);  /* a partial frame from long ago is not continued */
    for (i = 0; i < n; ++i) {
        count(link, ENB_C_BYTES_IN);
        rx_byte(link, data[i], now_ms);
    }
    if (n) {
        link->rx_last_ms = now_ms;
    }
}

void enb_tick(enb_link *link, uint32_t now_ms)
{
    if (link->rx_pos && (uint32_t)(now_ms - link->rx_last_ms) > ENB_RX_GAP_MS) {
        count(link, ENB_C_TRUNCATED);
        resync(link, now_ms);
    }
    if (!(link->flags & ENB_FLAG_NEUTRAL)
            && (uint32_t)(now_ms - link->last_valid_ms) > link->timeout_ms) {
        go_neutral(link);
        link->flags |= ENB_FLAG_TRIPPED;
        count(link, ENB_C_WATCHDOG_TRIPS);
    }
}

uint16_t enb_tx(enb_link *link, uint8_t *out, uint16_t cap)
{
    uint16_t n = 0;
    while (n < cap && link->tx_count) {
        out[n++] = link->tx_buf[link->tx_head];
        link->tx_head = (uint16_t)((link->tx_head + 1u) % ENB_TX_CAP);
        --link->tx_count;
    }
    return n;
}

uint16_t enb_duty(const enb_link *link, uint8_t ch)
{
    return ch < ENB_CHANNELS ? link->duty[ch] : 0u;
}

uint8_t enb_flags(const enb_link *link)
{
    return link->flags;
}

uint16_t enb_counter(const enb_link *link, uint8_t id)
{
    return id < ENB_C_COUNT ? link->counters[id] : 0u;
}

size_t enb_link_size(void)
{
    return sizeof(enb_link);
}
