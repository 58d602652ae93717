// The protocol's fixed sets, spelled once on the page side as the server declares them (colorgrid/enums.py: Role;
// server/protocol.py: Mode, GoalView, SeatStatus, RoomSeatStatus). Pages compare with these, never with a string
// literal; tests/test_sets_declared.py checks each value against the server's enum and that no page compares a
// set's value as a literal.
export const ROLE = Object.freeze({ LEADER: "leader", FOLLOWER: "follower" });
export const MODE = Object.freeze({ TURN: "turn", REALTIME: "realtime" });
export const GOAL_VIEW = Object.freeze({ HIDDEN: "hidden", SHOWN: "shown" });
export const SEAT_STATUS = Object.freeze({ PLAYING: "playing", RECONNECTING: "reconnecting", LEFT: "left" });
export const ROOM_SEAT_STATUS = Object.freeze({ OPEN: "open", JOINED: "joined", READY: "ready" });
